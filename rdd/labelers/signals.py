"""Signals labeler: names what the robot's own signals show in an interval, with no model and no annotation.

A segment is named by the hand state changes whose midpoint falls in it (``rdd.data.hand_events``:
"right hand closes", "left hand opens"; "gripper" for a single unnamed one) and by the arms that
move for at least half of its frames ("right arm moves", "both arms move"; "arm moves" when the
joints have no side). A segment where nothing moves is "hold still". The default labeler of
``python -m rdd decompose --write-lerobot`` when no other names the segments.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.checks import check_options, number
from rdd.data.episode import Episode
from rdd.data.hand_events import HandMove, arm_moving, episode_moves, smoothed_speed
from rdd.registry import register
from rdd.segments import Segment

OPTION_RULES = {"hand_delta": number(0.0, exclusive_min=True), "moving_fraction": number(0.0, 1.0),
                "smooth_s": number(0.0)}


def _hands(episode: Episode) -> tuple[np.ndarray | None, list[str], bool]:
    """(T, H) hand levels, a name per hand, and whether higher means open."""
    levels = episode.meta.get("hand_levels")
    grip = episode.meta.get("gripper") or {}
    if levels is None:
        if episode.gripper_open is None:
            return None, [], True
        return episode.gripper_open[:, None], ["gripper"], True
    levels = np.asarray(levels, dtype=np.float64)
    levels = levels[:, None] if levels.ndim == 1 else levels
    sides = list(grip.get("sides") or [])
    names = [f"{s} hand" if s else "gripper" for s in sides] if len(sides) == levels.shape[1] else (
        ["gripper"] if levels.shape[1] == 1 else [f"hand {h + 1}" for h in range(levels.shape[1])])
    return levels, names, bool(grip.get("open_above", True))


def _arms(episode: Episode) -> dict[str, np.ndarray]:
    """Joint velocities per arm name ("left", "right", or "" for unsided joints)."""
    v = episode.joint_velocities
    if v is None:
        return {}
    v = v[:, None] if v.ndim == 1 else v
    sides = episode.meta.get("arm_sides") or {}
    if not sides:
        return {"": v}
    return {side: v[:, idx] for side, idx in sorted(sides.items())}


def _join(parts: list[str]) -> str:
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


@register("labeler", "signals")
class SignalsLabeler:
    """Labels intervals from the episode's hand levels (or gripper flag) and joint velocities."""

    name = "signals"

    def __init__(self, hand_delta: float = 0.1, moving_fraction: float = 0.1, smooth_s: float = 0.1) -> None:
        opts = check_options("signals labeler", OPTION_RULES, {"hand_delta": hand_delta,
                             "moving_fraction": moving_fraction, "smooth_s": smooth_s})
        self.hand_delta, self.moving_fraction, self.smooth_s = (
            opts["hand_delta"], opts["moving_fraction"], opts["smooth_s"])

    def _signals(self, episode: Episode) -> tuple[list[HandMove], list[str], dict[str, np.ndarray]]:
        levels, names, open_above = _hands(episode)
        arms = _arms(episode)
        if levels is None and not arms:
            raise ValueError(f"episode {episode.name!r} has no hand, gripper or joint signals for the signals "
                             "labeler; name its segments with --labeler retrieval --label-db DB or "
                             "--fallback-instruction TEMPLATE")
        moves = [] if levels is None else episode_moves(levels, self.hand_delta, open_above)
        fps = float(episode.meta.get("fps") or 0)
        window = max(1, round(self.smooth_s * fps)) if fps else 1
        moving = arm_moving({side: smoothed_speed(v, window) for side, v in arms.items()}, self.moving_fraction)
        return moves, names, moving

    def label(self, episode: Episode, segment: Segment) -> str:
        """What the signals show in frames ``[start, end)``."""
        return self.label_all(episode, [segment])[0]

    def label_all(self, episode: Episode, segments: Sequence[Segment]) -> list[str]:
        """Labels of several intervals of one episode (its signals read once)."""
        moves, names, moving = self._signals(episode)
        return [self._name(int(s), int(e), moves, names, moving) for s, e in segments]

    @staticmethod
    def _name(start: int, end: int, moves: list[HandMove], names: list[str], moving: dict[str, np.ndarray]) -> str:
        arms = [side for side, m in moving.items() if end > start and m[start:end].mean() >= 0.5]
        parts = []
        if arms:
            parts.append("both arms move" if len(arms) == 2 and len(moving) == 2 else
                         _join([f"{s} arm" if s else "arm" for s in arms]) + (" move" if len(arms) > 1 else " moves"))
        changes: dict[str, list[str]] = {}
        for m in moves:
            # A segment shows the changes that complete inside it: a cut at a change's midpoint ends the
            # segment that led to it.
            if start < m.frame <= end or (start == 0 and m.frame == 0):
                changes.setdefault("opens" if m.opens else "closes", [])
                name = names[m.hand]
                if name not in changes["opens" if m.opens else "closes"]:
                    changes["opens" if m.opens else "closes"].append(name)
        for verb, hands in changes.items():
            both = len(hands) == 2 and all(h.endswith(" hand") for h in hands)
            plural = verb[:-1]
            parts.append(f"both hands {plural}" if both else
                         _join(hands) + (f" {plural}" if len(hands) > 1 else f" {verb}"))
        return _join(parts) if parts else "hold still"
