"""The frames of one LeRobot episode inside an mp4, decoded with PyAV on demand."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rdd.data.frames import update_with_file
from rdd.data.lerobot_dataset import _need


class VideoFrames:
    """Frames of one episode inside an mp4, decoded with PyAV on demand.

    Frame i is the decoded frame nearest to ``timestamps[i]`` (seconds in the file); a gap larger
    than ``tolerance_s`` is an error. ``max_side`` downsizes frames as they are decoded so long
    640x480 episodes do not fill memory.
    """

    def __init__(
        self,
        path: str | Path,
        timestamps: np.ndarray,
        tolerance_s: float,
        max_side: int | None = None,
    ):
        self.path = Path(path)
        self.timestamps = np.asarray(timestamps, dtype=np.float64)
        self.tolerance_s = float(tolerance_s)
        self.max_side = None if max_side is None else int(max_side)
        self._fingerprint: str | None = None

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def _to_array(self, frame) -> np.ndarray:
        if self.max_side is not None and max(frame.width, frame.height) > self.max_side:
            scale = self.max_side / max(frame.width, frame.height)
            frame = frame.reformat(
                width=max(1, round(frame.width * scale)), height=max(1, round(frame.height * scale))
            )
        return frame.to_ndarray(format="rgb24")

    def load(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """Decode the frames at ``indices`` (all when None) in one sequential pass."""
        av = _need("av")
        idx = np.arange(len(self)) if indices is None else np.asarray(indices, dtype=np.int64)
        if idx.size == 0:
            return np.zeros((0, 0, 0, 3), dtype=np.uint8)
        if idx.min() < 0 or idx.max() >= len(self):
            raise IndexError(f"{self.path}: frame index out of range [0, {len(self)})")
        wanted = np.unique(self.timestamps[idx])
        best_gap = np.full(wanted.shape, np.inf)
        best: list[np.ndarray | None] = [None] * len(wanted)
        lo, hi = wanted[0] - self.tolerance_s, wanted[-1] + self.tolerance_s
        try:
            container = av.open(str(self.path))
        except (OSError, av.error.FFmpegError) as exc:
            raise ValueError(f"cannot open video {self.path}: {exc}") from exc
        with container:
            stream = container.streams.video[0]
            if lo > 1.0:
                # Seek to a keyframe before the first wanted frame (v3.0 files hold many episodes).
                container.seek(int(max(0.0, lo - 1.0) / stream.time_base), stream=stream)
            for frame in container.decode(stream):
                t = frame.time
                if t is None or t < lo:
                    continue
                if t > hi:
                    break
                j = int(np.searchsorted(wanted, t))
                for k in (j - 1, j):
                    if 0 <= k < len(wanted) and abs(wanted[k] - t) < best_gap[k]:
                        best_gap[k] = abs(wanted[k] - t)
                        best[k] = self._to_array(frame)
        bad = np.nonzero(best_gap > self.tolerance_s)[0]
        if bad.size:
            raise ValueError(
                f"{self.path}: no video frame within {self.tolerance_s:.4f}s of timestamp "
                f"{wanted[bad[0]]:.4f}s ({bad.size} of {len(wanted)} frames missing)"
            )
        lookup = {float(t): k for k, t in enumerate(wanted)}
        return np.stack([best[lookup[float(self.timestamps[i])]] for i in idx]).astype(np.uint8)

    def fingerprint(self) -> str:
        """SHA-256 of the video bytes, the episode's timestamps and the resize option."""
        if self._fingerprint is None:
            h = update_with_file(hashlib.sha256(), self.path)
            h.update(self.timestamps.tobytes())
            h.update(str(self.max_side).encode())
            self._fingerprint = h.hexdigest()
        return self._fingerprint
