"""The ``Episode`` type every reader produces and every decomposer consumes."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rdd.data.frames import ArrayFrames, FrameSource
from rdd.segments import Segment


@dataclass
class Episode:
    """One demonstration: lazily loaded frames per view plus proprioception and annotations.

    Arrays are indexed by frame (length T). Optional fields are None when the source lacks them.
    """

    name: str
    views: Mapping[str, FrameSource]
    gripper_open: np.ndarray | None = None  # (T,) float, 1 = open, 0 = closed
    joint_positions: np.ndarray | None = None  # (T, J)
    joint_velocities: np.ndarray | None = None  # (T, J)
    ee_poses: np.ndarray | None = None  # (T, 7): xyz + quaternion xyzw
    goal: str = ""
    task: str = ""
    segments: list[Segment] | None = None  # a known (e.g. expert) segmentation, if any
    instructions: list[str] | None = None  # one per segment in ``segments``
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.views = {
            k: (ArrayFrames(v) if isinstance(v, np.ndarray) else v) for k, v in self.views.items()
        }
        lengths = {k: len(v) for k, v in self.views.items()}
        n = self.num_frames
        if len(set(lengths.values())) > 1:
            raise ValueError(f"episode {self.name!r}: views have different lengths {lengths}")
        for fname in ("gripper_open", "joint_positions", "joint_velocities", "ee_poses"):
            arr = getattr(self, fname)
            if arr is None:
                continue
            arr = np.asarray(arr, dtype=np.float64)
            setattr(self, fname, arr)
            if lengths and arr.shape[0] != n:
                raise ValueError(
                    f"episode {self.name!r}: field {fname!r} has {arr.shape[0]} rows, "
                    f"but the frames have {n}"
                )

    @property
    def num_frames(self) -> int:
        """Number of frames T."""
        if self.views:
            return len(next(iter(self.views.values())))
        for fname in ("gripper_open", "joint_positions", "joint_velocities", "ee_poses"):
            arr = getattr(self, fname)
            if arr is not None:
                return int(np.asarray(arr).shape[0])
        return 0

    def frames(self, view: str, indices: Sequence[int] | None = None) -> np.ndarray:
        """uint8 frames (N, H, W, 3) of ``view`` at ``indices`` (all when None)."""
        if view not in self.views:
            raise KeyError(
                f"episode {self.name!r} has no view {view!r}; available: {sorted(self.views)}"
            )
        return self.views[view].load(indices)

    def release(self) -> None:
        """Drop the frames (and lazily read arrays) loaded so far; they are read again if asked for.
        A job over many episodes calls this when it is done with one, so memory stays that of one."""
        for source in [*self.views.values(), *self.meta.values()]:
            release = getattr(source, "release", None)
            if callable(release):
                release()

    def fingerprint(self, views: Sequence[str] | None = None) -> str:
        """Content hash of the chosen views' frames (all views when None)."""
        h = hashlib.sha256()
        for v in sorted(views if views is not None else self.views):
            h.update(v.encode())
            h.update(self.views[v].fingerprint().encode()
                     if v in self.views else b"<missing>")
        return h.hexdigest()
