"""The RLBench keyframe heuristic of PerAct/RVT ("expert" segmentation).

Keyframes are where the gripper opens or closes, where the arm comes to rest, and the last frame.
"""

from __future__ import annotations

from itertools import pairwise
from typing import Literal

import numpy as np

from rdd.checks import number, one_of
from rdd.data.episode import Episode
from rdd.data.hand_events import (
    episode_moves,
    event_timescale,
    hand_arm_cuts,
    sample_period,
    smoothed_speed,
    still_runs,
)
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.registry import register
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


def scale_aware_keyframes(
    gripper_open: np.ndarray,
    velocities: np.ndarray,
    fps: float,
    stopping_fraction: float = 0.1,
    smooth_s: float = 0.1,
    min_stop_s: float = 0.2,
) -> list[int]:
    """Keyframes of recorded (real) data: gripper changes, the first frame of each rest, last frame.

    Velocities are in the dataset's own units per second. The speed ``max_j |v_j|`` is averaged over
    ``smooth_s`` seconds (finite differences of teleoperated positions are noisy) and the arm rests
    where it stays at or below ``stopping_fraction`` of the episode's peak speed (95th percentile)
    for ``min_stop_s`` seconds. Each rest counts once (RLBench's rule fires every 5 frames of a long
    rest), rests at the very start or end are not sub-task ends, and keyframes closer than
    ``min_stop_s`` to the previous one are merged into it.
    """
    g = np.asarray(gripper_open, dtype=np.float64).reshape(-1)
    v = np.asarray(velocities, dtype=np.float64)
    v = v[:, None] if v.ndim == 1 else v
    t = g.shape[0]
    if v.ndim != 2 or v.shape[0] != t:
        raise ValueError(f"velocities must be (T, J) with T = len(gripper_open) = {t}, got shape {v.shape}")
    if t == 0:
        return []
    speed = np.abs(v).max(axis=1) if v.shape[1] else np.zeros(t)
    window = max(1, round(smooth_s * fps))
    smoothed = np.convolve(speed, np.ones(window) / window, mode="same")
    peak = float(np.percentile(smoothed, 95))
    min_frames = max(1, round(min_stop_s * fps))
    candidates = set(np.flatnonzero(g[1:] != g[:-1]) + 1)
    if peak > 0:
        candidates |= {a for a, b in still_runs(smoothed, stopping_fraction * peak, min_frames) if 0 < a and b < t}
    keyframes: list[int] = []
    for k in sorted(int(c) for c in candidates):
        if k < t - 1 - min_frames and (not keyframes or k - keyframes[-1] >= min_frames):
            keyframes.append(k)
    return [*keyframes, t - 1] if t > 1 else keyframes


STOP_TESTS = ("auto", "absolute", "scale")
RULES = ("auto", "keyframes", "hands")


def uses_hand_rule(episode: Episode) -> bool:
    """Whether ``rule=auto`` cuts ``episode`` at hand events: it carries per-hand levels (LeRobot) of
    two hands or of a hand with several dims (a dexterous hand); a single gripper keeps the keyframe rule."""
    levels = episode.meta.get("hand_levels")
    groups = (episode.meta.get("gripper") or {}).get("indices") or []
    return levels is not None and (len(groups) > 1 or any(len(g) > 1 for g in groups))


def hand_rule_segments(episode: Episode, delta: float, stopping_fraction: float, smooth_s: float,
                       min_stop_s: float) -> tuple[list[tuple[int, int]], dict]:
    """The hands-and-arms rule (docs/lerobot.md): cuts at each hand's state changes and at arm rests
    between them, no segment shorter than the episode's event timescale unless a hand changes state."""
    levels = episode.meta.get("hand_levels")
    if levels is None:
        if episode.gripper_open is None:
            raise ValueError(f"episode {episode.name!r} has neither per-hand levels nor a gripper_open signal "
                             "for the expert option rule=hands")
        levels = episode.gripper_open[:, None]
    open_above = bool((episode.meta.get("gripper") or {}).get("open_above", True))
    moves = episode_moves(levels, delta, open_above)
    fps = float(episode.meta.get("fps") or 0)
    # The data's own event timescale: how long its hands take to change state (else min_stop_s).
    measured = event_timescale(moves)
    min_len = measured if measured is not None else max(1, round(min_stop_s * fps) if fps else 1)
    t = episode.num_frames
    v = episode.joint_velocities if episode.joint_velocities is not None else np.zeros((t, 0))
    speed = smoothed_speed(v, max(1, round(smooth_s * fps)) if fps else 1)
    floor = 2 * sample_period(levels)
    hand_cuts, arm_cuts = hand_arm_cuts(moves, speed, min_len, stopping_fraction, floor)
    bounds = [0, *sorted(set(hand_cuts) | set(arm_cuts)), t]
    meta = {"hand_cuts": hand_cuts, "arm_cuts": arm_cuts, "event_timescale": min_len, "min_frames": floor,
            "event_timescale_measured": measured is not None,
            "hand_events": [{"hand": m.hand, "frame": m.frame, "opens": m.opens} for m in moves]}
    return list(pairwise(bounds)), meta


@register("decomposer", "expert")
class ExpertDecomposer(Decomposer):
    """Segments at the RLBench keyframes of an episode's gripper state and velocities.

    ``stop_test``: ``absolute`` is RLBench's rule (``|v| <= stopping_delta`` per joint, per control
    step); ``scale`` is :func:`scale_aware_keyframes` in the dataset's own units and fps (for recorded
    robot data); ``auto`` picks ``scale`` when the episode declares its fps (LeRobot), else ``absolute``.
    ``rule``: ``keyframes`` is that keyframe rule; ``hands`` is :func:`hand_rule_segments` (hand state
    changes of at least ``hand_delta`` in the hand level's units, arm rests between them); ``auto``
    picks ``hands`` for episodes with dexterous or two hands (:func:`uses_hand_rule`).
    """

    name = "expert"
    OPTION_RULES = {
        "stopping_delta": number(0.0), "velocity_source": one_of("auto", "joint", "ee"),
        "ee_stopping_delta": number(0.0, allow_none=True), "stop_test": one_of(*STOP_TESTS),
        "stopping_fraction": number(0.0, 1.0), "smooth_s": number(0.0), "min_stop_s": number(0.0),
        "rule": one_of(*RULES), "hand_delta": number(0.0, exclusive_min=True),
    }

    def __init__(
        self,
        stopping_delta: float = 0.1,
        velocity_source: Literal["auto", "joint", "ee"] = "auto",
        ee_stopping_delta: float | None = None,
        stop_test: str = "auto",
        stopping_fraction: float = 0.1,
        smooth_s: float = 0.1,
        min_stop_s: float = 0.2,
        rule: str = "auto",
        hand_delta: float = 0.1,
    ):
        opts = self.check_options(
            velocity_source=velocity_source, stopping_delta=stopping_delta, ee_stopping_delta=ee_stopping_delta,
            stop_test=stop_test, stopping_fraction=stopping_fraction, smooth_s=smooth_s, min_stop_s=min_stop_s,
            rule=rule, hand_delta=hand_delta)
        self.rule, self.hand_delta = opts["rule"], opts["hand_delta"]
        self.velocity_source, self.stop_test = opts["velocity_source"], opts["stop_test"]
        self.stopping_delta, self.ee_stopping_delta = opts["stopping_delta"], opts["ee_stopping_delta"]
        self.stopping_fraction, self.smooth_s, self.min_stop_s = (
            opts["stopping_fraction"], opts["smooth_s"], opts["min_stop_s"])

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
        """Segments ending at the expert keyframes (the last frame always ends one), or the hand rule's."""
        if self.rule == "hands" or (self.rule == "auto" and uses_hand_rule(episode)):
            segments, meta = hand_rule_segments(episode, self.hand_delta, self.stopping_fraction, self.smooth_s,
                                                self.min_stop_s)
            return Decomposition(segments=segments,
                                 meta={"rule": "hands", "keypoints": [e - 1 for _, e in segments], **meta})
        if episode.gripper_open is None:
            raise ValueError(f"episode {episode.name!r} has no gripper_open signal for the expert rule "
                             "(LeRobot: name the gripper dims with --reader-option gripper_key=... "
                             "gripper_indices=[...])")
        velocities, delta, source = self._velocities(episode)
        fps = episode.meta.get("fps")
        test = self.stop_test
        if test == "auto":
            test = "scale" if fps else "absolute"
        if test == "scale":
            if not fps:
                raise ValueError(f"episode {episode.name!r} declares no fps (meta['fps']); "
                                 "the expert option stop_test=scale needs it (use stop_test=absolute)")
            per_second = velocities if source == "joint" else velocities * float(fps)
            keyframes = scale_aware_keyframes(episode.gripper_open, per_second, float(fps),
                                              self.stopping_fraction, self.smooth_s, self.min_stop_s)
        else:
            keyframes = keypoint_discovery(episode.gripper_open, velocities, delta)
        segments = keyframes_to_segments(keyframes, episode.num_frames)
        return Decomposition(
            segments=segments,
            meta={"keypoints": keyframes, "velocity_source": source, "stop_test": test},
        )
