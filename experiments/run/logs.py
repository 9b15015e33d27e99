"""What a run shows a person: progress bars for long steps, one line per stage, quiet libraries.

The terminal gets INFO lines (``conf/hydra/job_logging/harness.yaml``) and tqdm bars on stderr that
vanish when done (``rdd.progress``, the CLI's too); the run's log file also gets the DEBUG lines
(per-epoch losses, per-episode outcomes, tracebacks). Libraries that print their own bars and
notices (transformers' weight loading and shard writing) are silenced here, once per process.
"""

from __future__ import annotations

import logging
import warnings
from typing import Any

# The one progress bar (rdd is the bottom layer); the harness's modules import it from here.
from rdd.progress import progress, progress_enabled, show_progress

__all__ = ["progress", "progress_enabled", "quiet_libraries", "show_progress", "stage_lines"]


def quiet_libraries() -> None:
    """Silence library chatter that is not about this run (bars, deprecation notices)."""
    warnings.filterwarnings("ignore", category=FutureWarning, module=r"transformers\..*")
    warnings.filterwarnings("ignore", category=UserWarning, module=r"peft\..*")
    try:
        from transformers.utils import logging as hf_logging

        hf_logging.set_verbosity_error()
        hf_logging.disable_progress_bar()
    except ImportError:  # the planner extra is not installed: nothing to silence
        pass
    try:
        from huggingface_hub.utils import disable_progress_bars

        disable_progress_bars()
    except ImportError:
        pass
    for name in ("accelerate", "peft", "matplotlib", "PIL", "filelock", "urllib3"):
        logging.getLogger(name).setLevel(logging.WARNING)


def stage_lines(timings: dict[str, Any]) -> list[str]:
    """One line per stage: built or reused (from the stage cache) and its wall time."""
    lines = []
    for name, t in timings.items():
        built, reused = int(getattr(t, "built", 0)), int(getattr(t, "reused", 0))
        if built and reused:
            status = f"built {built}, reused {reused}"
        else:
            status = "reused" if t.cached else "built"
        lines.append(f"stage {name:<17} {status:<22} {t.seconds:8.1f} s")
    return lines
