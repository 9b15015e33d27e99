"""One progress bar per sweep (``python run.py -m ...``): finished runs / total, with rate and ETA.

A Hydra callback (``hydra.callbacks.sweep_progress`` in ``conf/config.yaml``) in the launching
process: at the start of a multirun it counts the jobs the sweep will launch (command-line sweeps
and the experiment's ``hydra.sweeper.params``, as Hydra's basic sweeper combines them) and polls the
sweep folder for finished ``results.json`` files, so the bar moves whichever launcher runs the jobs
(joblib workers, Slurm, Ray) as long as the sweep folder is visible here.
"""

from __future__ import annotations

import math
import sys
import threading
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from experiments.report.results import RESULTS_FILE


def sweep_size(config: DictConfig) -> int:
    """Number of jobs of the multirun described by ``config`` (its ``hydra`` node)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = OmegaConf.select(config, "hydra.sweeper.params") or {}
    lines = [f"{k}={v}" for k, v in params.items()]
    lines += list(OmegaConf.select(config, "hydra.overrides.task") or [])
    sizes: dict[str, int] = {}
    for override in OverridesParser.create().parse_overrides(lines):
        key = override.get_key_element()  # a command-line value replaces the experiment's sweep
        sizes[key] = len(list(override.sweep_string_iterator())) if override.is_sweep_override() else 1
    return math.prod(sizes.values()) if sizes else 1


def finished_runs(sweep_dir: Path) -> int:
    """How many jobs of the sweep in ``sweep_dir`` have written their results.json."""
    return sum(1 for _ in Path(sweep_dir).glob(f"*/{RESULTS_FILE}"))


class SweepProgress(Callback):
    """Draws the sweep's bar from the launching process while its jobs run."""

    def __init__(self, poll_s: float = 2.0) -> None:
        self.poll_s = float(poll_s)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # Launchers pickle the callbacks into their workers: the polling thread stays here.
    def __getstate__(self) -> dict[str, Any]:
        return {"poll_s": self.poll_s}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        """Start polling the sweep folder."""
        try:
            total = sweep_size(config)
        except Exception:  # an unusual sweeper: no bar rather than a failed sweep
            return
        sweep_dir = Path(str(config.hydra.sweep.dir))
        self._stop.clear()
        self._thread = threading.Thread(target=self._poll, args=(sweep_dir, total), daemon=True)
        self._thread.start()

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        """Draw the final count and stop polling."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None

    def _poll(self, sweep_dir: Path, total: int) -> None:
        from tqdm import tqdm

        # A terminal gets a bar; a log file one line per change in the count, not a redraw per poll.
        bar = (tqdm(total=total, desc="sweep", unit="run", file=sys.stderr, dynamic_ncols=True)
               if sys.stderr.isatty() else None)
        done = -1
        try:
            while True:
                stopping = self._stop.wait(self.poll_s)
                now = min(total, finished_runs(sweep_dir))
                if now != done:
                    done = now
                    if bar is None:
                        print(f"sweep: {done}/{total} runs finished", file=sys.stderr, flush=True)
                    else:
                        bar.update(done - bar.n)
                if stopping:
                    return
        finally:
            if bar is not None:
                bar.close()
