"""Progress for long CLI steps: a tqdm bar over frames (ETA) on a terminal, log lines with ``-v``."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterator, Sequence
from typing import Any

log = logging.getLogger("rdd")


def track_episodes(episodes: Sequence[Any], desc: str) -> Iterator[Any]:
    """Yield ``episodes``; a bar counts their frames (with ETA), and each finished one is logged (INFO)."""
    total = sum(int(e.num_frames) for e in episodes)
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a dependency; log lines still report progress
        tqdm = None
    bar = None if tqdm is None else tqdm(total=total, desc=desc, unit="frame", file=sys.stderr,
                                         disable=None, dynamic_ncols=True)
    done = 0
    t0 = time.monotonic()
    try:
        for i, ep in enumerate(episodes, 1):
            if bar is not None:
                bar.set_postfix_str(f"episode {i}/{len(episodes)}")
            start = time.monotonic()
            yield ep
            done += int(ep.num_frames)
            if bar is not None:
                bar.update(int(ep.num_frames))
            elapsed = time.monotonic() - t0
            eta = elapsed / done * (total - done) if done else 0.0
            log.info("%s: episode %d/%d %s (%d frames) in %.1fs; %d/%d frames, ETA %.0fs",
                     desc, i, len(episodes), ep.name, ep.num_frames, time.monotonic() - start,
                     done, total, eta)
    finally:
        if bar is not None:
            bar.close()
