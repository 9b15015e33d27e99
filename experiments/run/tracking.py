"""Weights & Biases logging of a run's config and metrics (``offline`` by default, no account needed)."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)
WANDB_MODES = ("online", "offline", "disabled")


class Tracker:
    """A wandb run, or nothing when ``mode=disabled``."""

    def __init__(self, wandb_cfg: Any, config: dict[str, Any], out_dir: Path, name: str):
        mode = str(wandb_cfg.mode)
        if mode not in WANDB_MODES:
            raise ValueError(f"wandb.mode={mode!r}: choose one of {WANDB_MODES}")
        self._run = None
        self._dir = out_dir
        if mode == "disabled":
            return
        try:
            import wandb
        except ImportError as exc:
            raise ImportError("wandb logging needs `pip install wandb` (or set wandb.mode=disabled)") from exc
        # wandb's own console capture and background service are not needed for offline files.
        os.environ.setdefault("WANDB_SILENT", "true")
        os.environ.setdefault("WANDB_CONSOLE", "off")
        self._run = wandb.init(
            project=wandb_cfg.project,
            entity=wandb_cfg.entity,
            group=wandb_cfg.group,
            tags=list(wandb_cfg.tags),
            name=name,
            mode=mode,
            dir=str(out_dir),
            config=config,
            reinit="finish_previous",
        )

    def log(self, metrics: dict[str, Any]) -> None:
        """Log scalar metrics (non-numbers are dropped)."""
        if self._run is None:
            return
        flat = {k: v for k, v in _flatten(metrics).items() if isinstance(v, int | float) and not isinstance(v, bool)}
        try:
            self._run.log(flat)
            for k, v in flat.items():
                self._run.summary[k] = v
        except Exception as exc:  # noqa: BLE001 - a tracker's failure must not become the run's
            self._lost(exc)

    def finish(self) -> None:
        """Close the run (files flushed)."""
        if self._run is None:
            return
        try:
            self._run.finish()
        except Exception as exc:  # noqa: BLE001 - a tracker's failure must not become the run's
            self._lost(exc)
        self._run = None

    def _lost(self, exc: Exception) -> None:
        """Give up on a run whose wandb service is gone, with one warning instead of the run's failure.

        A scheduler's kill (slurm, ``timeout``, guard) stops wandb's service, which runs in a session
        of its own, beside the harness: the harness's SIGTERM line and its cleanups must still come.
        """
        log.warning("wandb: the run's logging service is gone (%s: %s); its files under %s may be "
                    "incomplete (results.json is not)", type(exc).__name__, exc, self._dir)
        self._run = None
        import wandb

        try:  # unregisters wandb's exit hook, which would print the same failure's traceback at exit
            wandb.teardown()
        except Exception:  # noqa: BLE001 - the service is gone: there is nothing left to close
            pass


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "/"))
        else:
            out[key] = v
    return out
