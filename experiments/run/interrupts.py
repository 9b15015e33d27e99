"""How a harness run stops early: Ctrl-C and SIGTERM end it with one line, after its cleanups.

SIGTERM (a scheduler's kill, ``timeout``) ends Python at once by default, skipping every
``finally``: the stage lock stayed until it went stale and the half-built temporary folder until the
next run cleared it. :func:`run_stoppable` turns it into :class:`Terminated`, raised in the main
thread as Ctrl-C raises KeyboardInterrupt, so locks are released and temporary folders removed on the
way out. Either stop prints one line instead of a traceback and exits as a shell reports it (130 for
Ctrl-C, 143 for SIGTERM). What a SIGKILL leaves is still recovered by the next run (``stages.py``).
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable
from typing import Any

RESUME = "the stage cache keeps finished stages, rerun to resume"


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the main thread is: whatever cleans up after Ctrl-C cleans up after it too."""


def _terminate(signum: int, frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the cleanup short
    raise Terminated


def run_stoppable(fn: Callable[[], Any]) -> int:
    """Call ``fn`` with SIGTERM raising :class:`Terminated`; 0, or 130 / 143 after one line on stderr."""
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        fn()
    except Terminated:
        print(f"terminated (SIGTERM); {RESUME}", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print(f"interrupted; {RESUME}", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0
