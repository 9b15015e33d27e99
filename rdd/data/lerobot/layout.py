"""Which state dims of a LeRobot dataset are arm joints and which are grippers/hands, and the
open/closed flag of each hand.

The dims are inferred from the per-dimension names ``info.json`` gives a feature (names with
gripper, hand or finger are a hand's; one group per side).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

GRIPPER_WORDS = ("gripper", "hand", "finger")
SIDES = ("left", "right")
# A dexterous hand's four fingers by name (not the thumb, whose bend and rotation do not open it).
# The state view's opening is their median, not the mean of all the hand's dims: 4-fold
# cross-validation over G1 episodes 16-35 (databases of 15, calibrated), boundary F1 at +-5 against
# the hand rule 0.642 -> 0.670, the hysteresis annotation 0.572 -> 0.672.
FINGER_WORDS = ("pinky", "ring", "middle", "index")


def feature_names(info: dict[str, Any], key: str) -> list[str] | None:
    """The per-dimension names info.json gives feature ``key`` (flattened), or None."""
    names = (info.get("features", {}).get(key) or {}).get("names")
    if isinstance(names, dict):  # {"motors": [...]} in some datasets
        names = [n for group in names.values() for n in (group if isinstance(group, list) else [group])]
    if isinstance(names, list) and len(names) == 1 and isinstance(names[0], list):
        names = names[0]
    if isinstance(names, list) and names and all(isinstance(n, str) for n in names):
        return names
    return None


def infer_layout(names: Sequence[str]) -> tuple[list[int], dict[str, list[int]]]:
    """Arm dims and gripper/hand dims per side ("left", "right" or "") from per-dim names."""
    arm: list[int] = []
    hands: dict[str, list[int]] = {}
    for i, name in enumerate(names):
        low = name.lower()
        if any(w in low for w in GRIPPER_WORDS):
            side = next((s for s in SIDES if s in low), "")
            hands.setdefault(side, []).append(i)
        else:
            arm.append(i)
    return arm, hands


def arm_sides(names: Sequence[str], arm: Sequence[int]) -> dict[str, list[int]]:
    """Positions within ``arm`` (the arm dims) of each side's joints, for names that say left or right."""
    sides: dict[str, list[int]] = {}
    for pos, i in enumerate(arm):
        side = next((s for s in SIDES if s in names[i].lower()), None)
        if side is not None:
            sides.setdefault(side, []).append(pos)
    return sides


def hand_levels(values: np.ndarray, groups: Sequence[Sequence[int]], where: str) -> np.ndarray:
    """(T, H) level of each hand: the mean of its dims."""
    v = values if values.ndim == 2 else values[:, None]
    levels = np.zeros((v.shape[0], len(groups)))
    for h, group in enumerate(groups):
        bad = [i for i in group if not -v.shape[1] <= i < v.shape[1]]
        if bad:
            raise ValueError(f"reader option gripper_indices {bad} out of range for {where} with {v.shape[1]} dims")
        levels[:, h] = v[:, list(group)].mean(axis=1)
    return levels


def finger_levels(values: np.ndarray, groups: Sequence[Sequence[int]], names: Sequence[str] | None,
                  levels: np.ndarray) -> np.ndarray:
    """(T, H) opening of each hand: the median of its dims named for a finger (pinky, ring, middle,
    index), robust to the thumb and to one finger out of step; a hand without such names (a
    parallel gripper, unnamed dims) keeps its ``levels`` column (:func:`hand_levels`)."""
    openings = np.array(levels, dtype=np.float64)
    if names is None:
        return openings
    v = values if values.ndim == 2 else values[:, None]
    for h, group in enumerate(groups):
        fingers = [i for i in group if 0 <= i < len(names) and any(w in names[i].lower() for w in FINGER_WORDS)]
        if fingers:
            openings[:, h] = np.median(v[:, fingers], axis=1)
    return openings


def hand_flags(
    values: np.ndarray, groups: Sequence[Sequence[int]], threshold: float, hysteresis: float, open_above: bool,
    where: str,
) -> np.ndarray:
    """(T, H) open flags, one per hand: the mean of its dims against ``threshold`` with hysteresis.

    A hand switches state only when its mean passes ``threshold +- hysteresis``, so a resting hand
    whose level hovers near the threshold does not flicker between open and closed.
    """
    levels = hand_levels(values, groups, where)
    flags = np.zeros(levels.shape)
    for h in range(levels.shape[1]):
        level = levels[:, h]
        if not open_above:
            level = -level
        thr = threshold if open_above else -threshold
        state = bool(level[0] > thr) if len(level) else True
        for t, x in enumerate(level):
            if state and x < thr - hysteresis:
                state = False
            elif not state and x > thr + hysteresis:
                state = True
            flags[t, h] = float(state)
    return flags
