"""Progress bars for long steps, one kind for the CLI and the harness: tqdm on stderr, log lines with ``-v``.

Bars are drawn on a terminal only, unless a program decides for the whole process with
:func:`show_progress` (the harness: on, except in parallel sweep jobs, whose bars would interleave).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable, Iterator, Sequence
from typing import Any, TypeVar

T = TypeVar("T")
log = logging.getLogger("rdd")
_SHOW: bool | None = None  # None: on a terminal only


def show_progress(enabled: bool | None) -> None:
    """Draw bars always (True), never (False) or on a terminal only (None, the default)."""
    global _SHOW
    _SHOW = None if enabled is None else bool(enabled)


def progress_enabled() -> bool:
    """Whether long steps draw a progress bar (for libraries that take a ``progress`` flag)."""
    return sys.stderr.isatty() if _SHOW is None else _SHOW


def _bar(**options: Any):
    from tqdm import tqdm

    return tqdm(file=sys.stderr, disable=None if _SHOW is None else not _SHOW, dynamic_ncols=True, **options)


def progress(items: Iterable[T], desc: str, total: int | None = None, unit: str = "it",
             leave: bool = False) -> Iterator[T]:
    """``items`` with a bar (done/total, rate, ETA), cleared when finished unless ``leave``."""
    yield from _bar(iterable=items, desc=desc, total=total, unit=unit, leave=leave)


def track_episodes(episodes: Sequence[Any], desc: str) -> Iterator[Any]:
    """Yield ``episodes``; a bar counts their frames (with ETA), and each finished one is logged (INFO)."""
    total = sum(int(e.num_frames) for e in episodes)
    bar = _bar(total=total, desc=desc, unit="frame")
    done = 0
    t0 = time.monotonic()
    try:
        for i, ep in enumerate(episodes, 1):
            bar.set_postfix_str(f"episode {i}/{len(episodes)}")
            start = time.monotonic()
            yield ep
            done += int(ep.num_frames)
            bar.update(int(ep.num_frames))
            elapsed = time.monotonic() - t0
            eta = elapsed / done * (total - done) if done else 0.0
            log.info("%s: episode %d/%d %s (%d frames) in %.1fs; %d/%d frames, ETA %.0fs",
                     desc, i, len(episodes), ep.name, ep.num_frames, time.monotonic() - start,
                     done, total, eta)
    finally:
        bar.close()
