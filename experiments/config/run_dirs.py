"""Refuse a run or sweep folder that cannot be written before Hydra makes it: one line, exit 2.

Hydra creates ``hydra.run.dir`` (``hydra.sweep.dir`` for ``-m``) and the run's log file before the
task starts, so a read-only folder there was a Hydra traceback. This callback
(``hydra.callbacks.run_dirs`` in ``conf/config.yaml``) checks the folder first, with the same
check the CLI gives its outputs (:func:`rdd.atomic.check_writable`).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from rdd.atomic import check_writable


class RunDirCheck(Callback):
    """Hydra callback: the output folder of a run (or a sweep) must be writable."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        """Check ``hydra.run.dir``."""
        check_run_dir(config, "hydra.run.dir")

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        """Check ``hydra.sweep.dir``."""
        check_run_dir(config, "hydra.sweep.dir")


def check_run_dir(config: DictConfig, key: str) -> None:
    """Exit with one line naming ``key`` and its folder when nothing could be written there."""
    try:
        folder = OmegaConf.select(config, key)
    except Exception:  # an interpolation only Hydra's job can resolve: Hydra reports it there
        return
    if folder is None:
        return
    try:
        check_writable(Path(str(folder)) / ".hydra")  # the first thing Hydra writes there
    except OSError as exc:
        print(f"error: {key}={folder}: cannot be written: {exc.strerror}; choose another with {key}=DIR",
              file=sys.stderr)
        raise SystemExit(2) from None
