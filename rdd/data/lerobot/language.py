"""LeRobot's language columns, and the sub-tasks of one episode read from ``language_persistent``."""

from __future__ import annotations

import numpy as np

LANGUAGE_PERSISTENT = "language_persistent"
LANGUAGE_EVENTS = "language_events"


def read_subtasks(
    table, timestamps: np.ndarray, where: str
) -> tuple[list[tuple[int, int]], list[str]] | None:
    """Segments and instructions from the ``language_persistent`` subtask rows of one episode.

    Each row starts a segment at the frame whose timestamp equals the row's (float32) timestamp;
    it lasts until the next row's frame. None when the column is absent or holds no subtask rows.
    The first segment always starts at frame 0 (frames before the first row belong to it).
    """
    if LANGUAGE_PERSISTENT not in table.column_names or table.num_rows == 0:
        return None
    column = table.column(LANGUAGE_PERSISTENT)
    first = column[0].as_py() or []
    for i in (table.num_rows // 2, table.num_rows - 1):
        if (column[i].as_py() or []) != first:
            raise ValueError(f"{where}: column {LANGUAGE_PERSISTENT} differs between frames 0 and {i} "
                             "(LeRobot broadcasts the same rows to every frame of an episode)")
    rows = [r for r in first if isinstance(r, dict) and r.get("style") == "subtask"]
    if not rows:
        return None
    ts32 = timestamps.astype(np.float32)
    starts: dict[int, str] = {}
    for r in sorted(rows, key=lambda r: float(r.get("timestamp") or 0.0)):
        if r.get("timestamp") is None:
            raise ValueError(f"{where}: a {LANGUAGE_PERSISTENT} subtask row has no timestamp")
        hit = np.flatnonzero(ts32 == np.float32(r["timestamp"]))
        if hit.size == 0:
            raise ValueError(f"{where}: {LANGUAGE_PERSISTENT} subtask timestamp {r['timestamp']} "
                             "is not one of the episode's frame timestamps")
        frame = int(hit[0])
        if frame in starts:
            raise ValueError(f"{where}: two {LANGUAGE_PERSISTENT} subtask rows start at timestamp {r['timestamp']}")
        starts[frame] = "" if r.get("content") is None else str(r["content"])
    frames = sorted(starts)
    bounds = [0, *frames[1:], len(timestamps)]
    segments = [(bounds[j], bounds[j + 1]) for j in range(len(frames))]
    return segments, [starts[f] for f in frames]
