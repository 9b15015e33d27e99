"""Resumable training: the training loop's state saved every few minutes into a folder that outlives
a killed job, so the same stage run again goes on from the last save instead of from the start.

What is saved: the trainable parameters (a LoRA adapter, a projector, or the whole language model),
the optimizer and schedule, torch's random state, the data order's generator as the epoch began,
and how far the loop got (epoch, batch, losses so far). A resumed run takes the same batches in the
same order as an uninterrupted one, so it ends at the same weights. A save is written atomically, so
a kill during a save leaves the previous one; an unreadable save is discarded with a warning.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import torch

from rdd.atomic import atomic_file

log = logging.getLogger(__name__)

STATE_FILE = "state.pt"  # the loop's state at its last save
DONE_FILE = "done.pt"  # the loop finished: its trained parameters and log
EVERY_S = 300.0  # seconds of training between saves (a save of SmolLM2's full pretraining state takes a few seconds)


def trainable_state(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The parameters that train, by name (torch.save writes them out; no copy on the CPU)."""
    return {n: p.detach() for n, p in model.named_parameters() if p.requires_grad}


def trainable_params(model: torch.nn.Module, state: dict[str, torch.Tensor], where: Path) -> dict[str, torch.Tensor]:
    """``model``'s trainable parameters by name; a ValueError naming ``where`` unless ``state`` holds
    exactly them, shape for shape."""
    params = {n: p for n, p in model.named_parameters() if p.requires_grad}
    wrong = sorted(set(params) ^ set(state)) or [n for n in state if params[n].shape != state[n].shape]
    if wrong:
        raise ValueError(f"{where}: saved parameters do not fit this model ({wrong[0]} and {len(wrong) - 1} more)")
    return params


def copy_into(params: dict[str, torch.Tensor], state: dict[str, torch.Tensor]) -> None:
    """Copy ``state``'s tensors into the parameters of the same names."""
    with torch.no_grad():
        for name, value in state.items():
            params[name].copy_(value.to(params[name].device))


def _save(path: Path, obj: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path, "wb") as fh:
        torch.save(obj, fh)


def _load(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - a damaged save means: start over, never stop the job
        _discarded(path, "is unreadable", exc)
        return None


def _discarded(path: Path, why: str, exc: BaseException) -> None:
    log.warning("training save %s %s (%s); starting that training from the beginning",
                path, why, str(exc).splitlines()[0] if str(exc) else type(exc).__name__)


def _rng_state() -> dict[str, Any]:
    cuda = torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None
    return {"cpu": torch.get_rng_state(), "cuda": cuda}


def _set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["cpu"])
    if state["cuda"] is not None and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def save_state(folder: Path, model, optimizer, scheduler, progress: dict[str, Any]) -> None:
    """Save the loop's state into ``folder`` (``progress``: epoch, batch, losses, generator state...)."""
    _save(folder / STATE_FILE, {"model": trainable_state(model), "optimizer": optimizer.state_dict(),
                                "scheduler": scheduler.state_dict(), "rng": _rng_state(),
                                "progress": progress})


def load_state(folder: Path, model, optimizer, scheduler) -> dict[str, Any] | None:
    """Restore the last save in ``folder`` into the model, optimizer, schedule and torch's random
    state; its progress, or None when there is no usable save."""
    path = folder / STATE_FILE
    state = _load(path)
    if state is None:
        return None
    try:  # everything checked or loaded into the optimizer before the model's parameters change
        params = trainable_params(model, state["model"], path)
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        progress = dict(state["progress"])
    except (ValueError, KeyError, TypeError, RuntimeError) as exc:
        _discarded(path, "does not fit this training", exc)
        return None
    copy_into(params, state["model"])
    _set_rng_state(state["rng"])
    return progress


def save_done(folder: Path, model, result: dict[str, Any]) -> None:
    """Record that the loop finished: its trained parameters and its log (``result``)."""
    _save(folder / DONE_FILE, {"model": trainable_state(model), "result": result})
    (folder / STATE_FILE).unlink(missing_ok=True)


def load_done(folder: Path, model) -> dict[str, Any] | None:
    """The finished loop's log, its parameters copied into ``model``; None when it did not finish."""
    path = folder / DONE_FILE
    done = _load(path)
    if done is None:
        return None
    try:
        copy_into(trainable_params(model, done["model"], path), done["model"])
        return dict(done["result"])
    except (ValueError, KeyError, TypeError) as exc:
        _discarded(path, "does not fit this training", exc)
        return None
