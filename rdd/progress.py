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


class EpisodeBar:
    """One bar over a job's episodes, counting their frames (with ETA); each finished episode is
    logged (INFO, shown with ``-v``). Episodes done before (a resumed run's) start the bar at ``done``."""

    def __init__(self, desc: str, count: int, total_frames: int, done: int = 0, done_frames: int = 0):
        self.desc, self.count, self.total = desc, int(count), int(total_frames)
        self.done, self.frames = int(done), int(done_frames)
        self._start_frames, self._t0 = self.frames, time.monotonic()
        self._bar = _bar(total=self.total, initial=self.frames, desc=desc, unit="frame")
        self._bar.set_postfix_str(f"episode {self.done}/{self.count}")

    def advance(self, name: str, frames: int, seconds: float) -> None:
        """Count one finished episode of ``frames`` frames that took ``seconds``."""
        self.done += 1
        self.frames += int(frames)
        self._bar.update(int(frames))
        self._bar.set_postfix_str(f"episode {self.done}/{self.count}")
        run = self.frames - self._start_frames
        eta = (time.monotonic() - self._t0) / run * (self.total - self.frames) if run else 0.0
        log.info("%s: episode %d/%d %s (%d frames) in %.1fs; %d/%d frames, ETA %.0fs",
                 self.desc, self.done, self.count, name, frames, seconds, self.frames, self.total, eta)

    def close(self) -> None:
        """Remove the bar."""
        self._bar.close()

    def __enter__(self) -> EpisodeBar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def track_episodes(episodes: Sequence[Any], desc: str) -> Iterator[Any]:
    """Yield ``episodes``; a bar counts their frames (with ETA), and each finished one is logged (INFO)."""
    with EpisodeBar(desc, len(episodes), sum(int(e.num_frames) for e in episodes)) as bar:
        for ep in episodes:
            start = time.monotonic()
            yield ep
            bar.advance(ep.name, int(ep.num_frames), time.monotonic() - start)
