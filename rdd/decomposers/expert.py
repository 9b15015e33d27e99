"""The RLBench keyframe heuristic of PerAct/RVT ("expert" segmentation).

Keyframes are where the gripper opens or closes, where the arm comes to rest, and the last frame.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from rdd.data.episode import Episode
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.segments import keyframes_to_segments


def _is_stopped(
    gripper_open: np.ndarray,
    velocities: np.ndarray,
    i: int,
    stopped_buffer: int,
    stopping_delta: float,
) -> bool:
    """The rule's "arm stopped" test at frame ``i``.

    Frames i-1 and i-2 use Python's negative indexing at i < 2 (they wrap to the end), exactly
    as the reference implementation indexes its list of observations.
    """
    t = len(gripper_open)
    next_is_not_final = i == t - 2
    gripper_state_no_change = i < t - 2 and (
        gripper_open[i] == gripper_open[i + 1]
        and gripper_open[i] == gripper_open[i - 1]
        and gripper_open[i - 2] == gripper_open[i - 1]
    )
    # np.allclose(v, 0, atol=d) is |v| <= d elementwise (NaN counts as moving).
    small_delta = bool(np.all(np.abs(velocities[i]) <= stopping_delta))
    return stopped_buffer <= 0 and small_delta and not next_is_not_final and gripper_state_no_change


def keypoint_discovery(
    gripper_open: np.ndarray, joint_velocities: np.ndarray, stopping_delta: float = 0.1
) -> list[int]:
    """RLBench keyframes: gripper changes, arm stops (debounced by a 4-frame buffer), last frame."""
    g = np.asarray(gripper_open, dtype=np.float64).reshape(-1)
    v = np.asarray(joint_velocities, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.ndim != 2 or v.shape[0] != g.shape[0]:
        raise ValueError(
            f"joint_velocities must be (T, J) with T = len(gripper_open) = {g.shape[0]}, "
            f"got shape {v.shape}"
        )
    keypoints: list[int] = []
    if g.shape[0] == 0:
        return keypoints
    prev_gripper = g[0]
    stopped_buffer = 0
    last = g.shape[0] - 1
    for i in range(g.shape[0]):
        stopped = _is_stopped(g, v, i, stopped_buffer, stopping_delta)
        stopped_buffer = 4 if stopped else stopped_buffer - 1
        if i != 0 and (g[i] != prev_gripper or i == last or stopped):
            keypoints.append(i)
        prev_gripper = g[i]
    if len(keypoints) > 1 and keypoints[-1] - 1 == keypoints[-2]:
        keypoints.pop(-2)
    return keypoints


def ee_velocities(ee_poses: np.ndarray) -> np.ndarray:
    """Per-frame end-effector position change (units per frame; first frame 0), shape (T, 3)."""
    pos = np.asarray(ee_poses, dtype=np.float64)[:, :3]
    vel = np.zeros_like(pos)
    vel[1:] = pos[1:] - pos[:-1]
    return vel


class ExpertDecomposer(Decomposer):
    """Segments at the RLBench keyframes of an episode's gripper state and velocities."""

    name = "expert"

    def __init__(
        self,
        stopping_delta: float = 0.1,
        velocity_source: Literal["auto", "joint", "ee"] = "auto",
        ee_stopping_delta: float | None = None,
    ):
        if velocity_source not in ("auto", "joint", "ee"):
            raise ValueError(
                f"velocity_source must be 'auto', 'joint' or 'ee', got {velocity_source!r}"
            )
        self.stopping_delta = float(stopping_delta)
        self.velocity_source = velocity_source
        self.ee_stopping_delta = ee_stopping_delta

    def _velocities(self, episode: Episode) -> tuple[np.ndarray, float, str]:
        use_joint = self.velocity_source == "joint" or (
            self.velocity_source == "auto" and episode.joint_velocities is not None
        )
        if use_joint:
            if episode.joint_velocities is None:
                raise ValueError(f"episode {episode.name!r} has no joint_velocities (velocity_source='joint')")
            return episode.joint_velocities, self.stopping_delta, "joint"
        if episode.ee_poses is None:
            raise ValueError(
                f"episode {episode.name!r} has neither joint_velocities nor ee_poses; "
                "the expert rule needs one of them"
            )
        delta = self.stopping_delta if self.ee_stopping_delta is None else self.ee_stopping_delta
        return ee_velocities(episode.ee_poses), float(delta), "ee"

    def decompose(self, episode: Episode) -> Decomposition:
        """Segments ending at the expert keyframes (the last frame always ends one)."""
        if episode.gripper_open is None:
            raise ValueError(f"episode {episode.name!r} has no gripper_open signal for the expert rule")
        velocities, delta, source = self._velocities(episode)
        keyframes = keypoint_discovery(episode.gripper_open, velocities, delta)
        segments = keyframes_to_segments(keyframes, episode.num_frames)
        return Decomposition(
            segments=segments, meta={"keypoints": keyframes, "velocity_source": source}
        )
