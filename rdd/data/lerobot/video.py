"""The frames of one LeRobot episode inside an mp4, decoded with PyAV on demand."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from rdd.data.frames import file_digest
from rdd.data.lerobot.dataset import need


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

    def _indices(self, indices: Sequence[int] | None) -> np.ndarray:
        idx = np.arange(len(self)) if indices is None else np.asarray(indices, dtype=np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= len(self)):
            raise IndexError(f"{self.path}: frame index out of range [0, {len(self)})")
        return idx

    def _decode(self, wanted: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
        """``(k, frame nearest to wanted[k])`` for sorted unique ``wanted``, in order of k, each as
        soon as no later frame can be nearer: one sequential pass over the file.

        Only frames within the tolerance of a wanted timestamp are converted to arrays. A wanted
        timestamp without such a frame is a ValueError, raised after the pass (it counts them all).
        """
        av = need("av")
        tol = self.tolerance_s
        best_gap = np.full(wanted.shape, np.inf)
        best: list[np.ndarray | None] = [None] * len(wanted)
        done, failed = 0, False
        lo, hi = wanted[0] - tol, wanted[-1] + tol
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
                # Frames come in time order: a timestamp more than tol behind this one is settled.
                while done < len(wanted) and t > wanted[done] + tol:
                    failed = failed or best[done] is None
                    if not failed:
                        yield done, best[done]
                    best[done] = None
                    done += 1
                j = int(np.searchsorted(wanted, t))
                for k in (j - 1, j):
                    if 0 <= k < len(wanted) and abs(wanted[k] - t) < best_gap[k] and abs(wanted[k] - t) <= tol:
                        best_gap[k] = abs(wanted[k] - t)
                        best[k] = None if failed else self._to_array(frame)
        bad = np.nonzero(best_gap > tol)[0]
        if bad.size:
            raise ValueError(
                f"{self.path}: no video frame within {tol:.4f}s of timestamp "
                f"{wanted[bad[0]]:.4f}s ({bad.size} of {len(wanted)} frames missing)"
            )
        for k in range(done, len(wanted)):
            yield k, best[k]

    def load(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """Decode the frames at ``indices`` (all when None) in one sequential pass."""
        idx = self._indices(indices)
        if idx.size == 0:
            return np.zeros((0, 0, 0, 3), dtype=np.uint8)
        wanted, slot = np.unique(self.timestamps[idx], return_inverse=True)
        frames = dict(self._decode(wanted))
        return np.stack([frames[k] for k in slot]).astype(np.uint8, copy=False)

    def iter_load(self, indices: Sequence[int] | None = None, chunk: int = 32) -> Iterator[np.ndarray]:
        """The frames of ``load(indices)`` in order, ``chunk`` at a time, each chunk yielded as soon
        as it is decoded (so an encoder can work on it while the next is decoded)."""
        idx = self._indices(indices)
        if idx.size == 0:
            return
        ts = self.timestamps[idx]
        if np.any(np.diff(ts) < 0):  # out of time order: the rows are only known after the pass
            frames = self.load(idx)
            for start in range(0, len(frames), chunk):
                yield frames[start : start + chunk]
            return
        wanted, slot = np.unique(ts, return_inverse=True)
        pending: list[np.ndarray] = []
        row = 0
        for k, frame in self._decode(wanted):
            while row < len(slot) and slot[row] == k:
                pending.append(frame)
                row += 1
                if len(pending) == chunk:
                    yield np.stack(pending)
                    pending = []
        if pending:
            yield np.stack(pending)

    def fingerprint(self) -> str:
        """SHA-256 of the video file's digest, the episode's timestamps and the resize option.

        The file's digest (:func:`rdd.data.frames.file_digest`) is computed once per process, not
        once per episode: a LeRobot v3.0 video file holds many episodes.
        """
        if self._fingerprint is None:
            h = hashlib.sha256(file_digest(self.path).encode())
            h.update(self.timestamps.tobytes())
            h.update(str(self.max_side).encode())
            self._fingerprint = h.hexdigest()
        return self._fingerprint
