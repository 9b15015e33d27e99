"""Hand and arm events of recorded robot data: when each hand closes or opens, when each arm moves.

A hand's *level* is the mean of its dims (a gripper's opening, a dexterous hand's finger joints).
It changes state where the level makes a move of at least ``delta`` between two turning points
(a zigzag filter: smaller wiggles, such as a hand resting near a threshold or the steps of a
quantised signal, are not moves). The move's *event* frame is where the level crosses half way
between the two turning points, and its *duration* is the time it takes from 10 % to 90 % of the
move. The median duration of an episode's moves is the data's own event timescale.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np


@dataclass(frozen=True)
class HandMove:
    """One change of a hand's state: the level goes from turning point ``start`` to ``end``."""

    hand: int
    start: int
    end: int
    frame: int  # where the level crosses half way between start and end: the state changes here
    duration: int  # frames from 10 % to 90 % of the move
    opens: bool  # True when the hand opens (its level moves towards open)


def turning_points(level: np.ndarray, delta: float) -> list[int]:
    """Frames of the alternating extremes of ``level`` between which it moves by at least ``delta``
    (empty when it never does). The first is where the first move starts, the last where the last ends."""
    x = np.asarray(level, dtype=np.float64).reshape(-1)
    if x.size == 0:
        return []
    points: list[int] = []
    trend = 0  # +1 rising, -1 falling, 0 before the first move
    ext = lo = hi = 0  # ext: the extreme since the last turning point; lo/hi: extremes before the first move
    for i in range(1, x.size):
        if trend == 0:
            lo = i if x[i] < x[lo] else lo
            hi = i if x[i] > x[hi] else hi
            if x[hi] - x[lo] >= delta:  # one of them is i: the first move starts at the other
                points, ext, trend = ([lo], hi, 1) if lo < hi else ([hi], lo, -1)
        elif (x[i] - x[ext]) * trend > 0:
            ext = i
        elif abs(x[ext] - x[i]) >= delta:
            points.append(ext)
            ext, trend = i, -trend
    # The leg to the last extreme is a move of at least delta by construction.
    return [*points, ext] if trend else []


def _crossing(x: np.ndarray, a: int, b: int, fraction: float) -> int:
    """First frame in ``(a, b]`` where the level has covered ``fraction`` of the move from a to b."""
    target = x[a] + fraction * (x[b] - x[a])
    seg = x[a + 1:b + 1]
    passed = seg >= target if x[b] > x[a] else seg <= target
    return a + 1 + int(np.argmax(passed))


def hand_moves(level: np.ndarray, delta: float, hand: int = 0, open_above: bool = True) -> list[HandMove]:
    """The state changes of one hand (see the module docstring)."""
    x = np.asarray(level, dtype=np.float64).reshape(-1)
    pts = turning_points(x, delta)
    moves = []
    for a, b in pairwise(pts):
        if abs(x[b] - x[a]) < delta:
            continue
        rising = bool(x[b] > x[a])
        moves.append(HandMove(hand=hand, start=a, end=b, frame=_crossing(x, a, b, 0.5),
                              duration=max(1, _crossing(x, a, b, 0.9) - _crossing(x, a, b, 0.1)),
                              opens=rising == open_above))
    return moves


def event_timescale(moves: list[HandMove]) -> int | None:
    """The data's event timescale in frames: the median duration of its hands' moves (None without moves)."""
    if not moves:
        return None
    return max(1, int(round(float(np.median([m.duration for m in moves])))))


def sample_period(levels: np.ndarray) -> int:
    """Frames between updates of the hand signal: the median run of unchanged values (1 when every frame
    is new). Hands are often sampled slower than the cameras (about 9 Hz under 30 fps on a Unitree G1)."""
    lv = np.asarray(levels, dtype=np.float64)
    lv = lv[:, None] if lv.ndim == 1 else lv
    runs = [r for h in range(lv.shape[1])
            for r in np.diff(np.flatnonzero(np.diff(lv[:, h]) != 0)).tolist()]
    return max(1, int(round(float(np.median(runs))))) if runs else 1


def smoothed_speed(velocities: np.ndarray, window: int) -> np.ndarray:
    """``max_j |v_j|`` per frame, averaged over ``window`` frames (finite differences are noisy)."""
    v = np.asarray(velocities, dtype=np.float64)
    v = v[:, None] if v.ndim == 1 else v
    speed = np.abs(v).max(axis=1) if v.shape[1] else np.zeros(v.shape[0])
    w = max(1, int(window))
    if w == 1 or speed.size == 0:
        return speed
    # Edge-padded so the first and last frames are not pulled towards zero.
    padded = np.pad(speed, (w // 2, w - 1 - w // 2), mode="edge")
    return np.convolve(padded, np.ones(w) / w, mode="valid")


def still_runs(speed: np.ndarray, threshold: float, min_frames: int) -> list[tuple[int, int]]:
    """Maximal runs ``[a, b)`` of at least ``min_frames`` frames with ``speed <= threshold``."""
    still = np.concatenate([[False], np.asarray(speed) <= threshold, [False]])
    edges = np.flatnonzero(np.diff(still.astype(np.int8)))
    runs = list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))
    return [(a, b) for a, b in runs if b - a >= min_frames]


def arm_moving(speeds: dict[str, np.ndarray], fraction: float) -> dict[str, np.ndarray]:
    """Frames where each arm moves: its speed above ``fraction`` of the episode's peak, the 95th
    percentile of the fastest arm's speed (so an idle arm's noise is not motion)."""
    if not speeds:
        return {}
    fastest = np.max(np.stack([np.asarray(s, dtype=np.float64) for s in speeds.values()]), axis=0)
    peak = float(np.percentile(fastest, 95)) if fastest.size else 0.0
    return {k: (np.asarray(s) > fraction * peak) if peak > 0 else np.zeros(np.shape(s), dtype=bool)
            for k, s in speeds.items()}


def episode_moves(levels: np.ndarray, delta: float, open_above: bool = True) -> list[HandMove]:
    """The state changes of every hand of a (T, H) level array, in frame order."""
    lv = np.asarray(levels, dtype=np.float64)
    lv = lv[:, None] if lv.ndim == 1 else lv
    moves = [m for h in range(lv.shape[1]) for m in hand_moves(lv[:, h], delta, h, open_above)]
    return sorted(moves, key=lambda m: (m.frame, m.hand))


def _merge_hands(frames_hands: list[tuple[int, int]], min_len: int) -> list[int]:
    """Cut frames of hand events; events of different hands less than ``min_len`` apart are one
    simultaneous change (their moves overlap) and give one cut at their mean frame."""
    groups: list[list[tuple[int, int]]] = []
    for f, h in frames_hands:
        g = groups[-1] if groups else None
        if g and f - g[0][0] < min_len and h not in {x[1] for x in g}:
            g.append((f, h))
        else:
            groups.append([(f, h)])
    return [int(round(np.mean([f for f, _ in g]))) for g in groups]


def _keep_floor(cuts: list[int], t: int, floor: int) -> list[int]:
    """``cuts`` without those that leave a segment shorter than ``floor`` frames (the later one goes)."""
    kept: list[int] = []
    for c in cuts:
        if c - (kept[-1] if kept else 0) >= floor:
            kept.append(c)
    while kept and t - kept[-1] < floor:
        kept.pop()
    return kept


def hand_arm_cuts(
    moves: list[HandMove], arm_speed: np.ndarray, min_len: int, stopping_fraction: float, floor: int = 1,
) -> tuple[list[int], list[int]]:
    """The rule's cuts (first frames of segments 2..n): (hand-event cuts, arm-rest cuts).

    Every hand event cuts (simultaneous events of different hands once). Between two cuts, the arm
    rests where its speed (the fastest arm's, smoothed) stays at or below ``stopping_fraction`` of
    the episode's peak for at least ``min_len`` frames; each such rest cuts at its slowest frame when
    both sides keep at least ``min_len`` frames, so no segment is shorter than the data's event
    timescale unless a hand changes state at one of its ends. No segment at all is shorter than
    ``floor`` frames (two updates of the hand signal: a shorter one cannot show a state of its own).
    """
    speed = np.asarray(arm_speed, dtype=np.float64).reshape(-1)
    t = speed.size
    hand_cuts = _keep_floor([c for c in _merge_hands([(m.frame, m.hand) for m in moves], min_len) if 0 < c < t],
                            t, floor)
    peak = float(np.percentile(speed, 95)) if t else 0.0
    rests = still_runs(speed, stopping_fraction * peak, min_len) if peak > 0 else []
    bounds = [0, *hand_cuts, t]
    arm_cuts = []
    for a, b in pairwise(bounds):
        for r0, r1 in rests:
            if r0 >= a and r1 <= b:
                c = r0 + int(np.argmin(speed[r0:r1]))
                prev = arm_cuts[-1] if arm_cuts and arm_cuts[-1] > a else a
                if c - prev >= min_len and b - c >= min_len:
                    arm_cuts.append(c)
    return hand_cuts, arm_cuts
