"""The low-level policy's interface: ``reset(goal)`` then ``act(observation, instruction)``."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class KeyframeAction:
    """Next keyframe: target end-effector position, orientation (quaternion xyzw) and gripper state."""

    position: np.ndarray  # (3,) metres, world frame
    quaternion: np.ndarray  # (4,) xyzw, unit norm
    gripper_open: bool

    def __post_init__(self) -> None:
        pos = np.asarray(self.position, dtype=np.float64).reshape(-1)
        quat = np.asarray(self.quaternion, dtype=np.float64).reshape(-1)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"KeyframeAction.position must be 3 finite numbers, got {self.position!r}")
        norm = float(np.linalg.norm(quat)) if quat.shape == (4,) else 0.0
        if quat.shape != (4,) or not np.isfinite(norm) or norm < 1e-8:
            raise ValueError(
                f"KeyframeAction.quaternion must be 4 finite numbers with non-zero norm, got {self.quaternion!r}"
            )
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "quaternion", quat / norm)
        object.__setattr__(self, "gripper_open", bool(self.gripper_open))

    def to_array(self) -> np.ndarray:
        """Flat (8,) array: xyz, quaternion xyzw, gripper (1 = open)."""
        return np.concatenate([self.position, self.quaternion, [1.0 if self.gripper_open else 0.0]])

    @classmethod
    def from_array(cls, arr: np.ndarray) -> KeyframeAction:
        """Inverse of :meth:`to_array`; the gripper is open when its entry is >= 0.5."""
        a = np.asarray(arr, dtype=np.float64).reshape(-1)
        if a.shape != (8,):
            raise ValueError(f"a keyframe array has 8 entries (xyz, quat xyzw, gripper), got {a.shape}")
        return cls(position=a[:3], quaternion=a[3:7], gripper_open=bool(a[7] >= 0.5))


class Policy(ABC):
    """A language-conditioned keyframe policy."""

    @abstractmethod
    def reset(self, goal: str) -> None:
        """Start a new episode whose overall language goal is ``goal``."""

    @abstractmethod
    def act(self, observation: Mapping[str, Any], instruction: str) -> KeyframeAction:
        """Next keyframe for ``instruction`` given the current ``observation``."""
