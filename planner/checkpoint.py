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
    """The parameters that train, by name, copied to the CPU."""
    return {n: p.detach().cpu().clone() for n, p in model.named_parameters() if p.requires_grad}


def load_trainable(model: torch.nn.Module, state: dict[str, torch.Tensor], where: Path) -> None:
    """Copy ``state``'s parameters into ``model``; a ValueError naming ``where`` when they do not fit."""
    params = dict(model.named_parameters())
    missing = [n for n in state if n not in params or params[n].shape != state[n].shape]
    if missing:
        raise ValueError(f"{where}: saved parameters do not fit this model ({missing[0]} and {len(missing) - 1} more)")
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
        log.warning("training save %s is unreadable (%s); starting that training from the beginning",
                    path, str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        return None


def save_state(folder: Path, model, optimizer, scheduler, progress: dict[str, Any]) -> None:
    """Save the loop's state into ``folder`` (``progress``: epoch, batch, losses, generator state...)."""
    _save(folder / STATE_FILE, {"model": trainable_state(model), "optimizer": optimizer.state_dict(),
                                "scheduler": scheduler.state_dict(), "torch_rng": torch.get_rng_state(),
                                "progress": progress})


def load_state(folder: Path, model, optimizer, scheduler) -> dict[str, Any] | None:
    """Restore the last save in ``folder`` into the model, optimizer, schedule and torch's random
    state; its progress, or None when there is no usable save."""
    state = _load(folder / STATE_FILE)
    if state is None:
        return None
    load_trainable(model, state["model"], folder / STATE_FILE)
    optimizer.load_state_dict(state["optimizer"])
    scheduler.load_state_dict(state["scheduler"])
    torch.set_rng_state(state["torch_rng"])
    return state["progress"]


def save_done(folder: Path, model, result: dict[str, Any]) -> None:
    """Record that the loop finished: its trained parameters and its log (``result``)."""
    _save(folder / DONE_FILE, {"model": trainable_state(model), "result": result})
    (folder / STATE_FILE).unlink(missing_ok=True)


def load_done(folder: Path, model) -> dict[str, Any] | None:
    """The finished loop's log, its parameters copied into ``model``; None when it did not finish."""
    done = _load(folder / DONE_FILE)
    if done is None:
        return None
    load_trainable(model, done["model"], folder / DONE_FILE)
    return done["result"]
