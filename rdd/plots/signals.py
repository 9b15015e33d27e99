"""The robot's own signals under a timeline: each hand's level and each arm's speed, with the cuts."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.data.episode import Episode
from rdd.data.hand_events import smoothed_speed


def episode_signals(episode: Episode) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(hand name -> level, arm name -> speed) of ``episode``; empty dicts when it has none."""
    hands: dict[str, np.ndarray] = {}
    levels = episode.meta.get("hand_levels")
    if levels is not None:
        lv = np.asarray(levels, dtype=np.float64)
        lv = lv[:, None] if lv.ndim == 1 else lv
        sides = list((episode.meta.get("gripper") or {}).get("sides") or [])
        for h in range(lv.shape[1]):
            side = sides[h] if len(sides) == lv.shape[1] else ""
            hands[f"{side} hand" if side else f"hand {h + 1}" if lv.shape[1] > 1 else "gripper"] = lv[:, h]
    elif episode.gripper_open is not None:
        hands["gripper open"] = episode.gripper_open
    arms: dict[str, np.ndarray] = {}
    v = episode.joint_velocities
    if v is not None:
        v = v[:, None] if v.ndim == 1 else v
        fps = float(episode.meta.get("fps") or 0)
        window = max(1, round(0.1 * fps)) if fps else 1
        sides = episode.meta.get("arm_sides") or {"": list(range(v.shape[1]))}
        for side, idx in sorted(sides.items()):
            arms[f"{side} arm speed" if side else "arm speed"] = smoothed_speed(v[:, idx], window)
    return hands, arms


def has_signals(episode: Episode) -> bool:
    """Whether ``episode`` carries per-hand levels or sided arms (the LeRobot reader's) to draw."""
    return episode.meta.get("hand_levels") is not None or bool(episode.meta.get("arm_sides"))


def draw_signals(ax, episode: Episode, cuts: Sequence[int], label: str) -> None:
    """Hand levels (left axis) and arm speeds (right axis, dashed) of ``episode``, the cuts of row
    ``label`` as vertical lines."""
    hands, arms = episode_signals(episode)
    t = np.arange(episode.num_frames)
    for name, level in hands.items():
        ax.plot(t, level, linewidth=1.2, label=name)
    ax.set_ylabel("hand level", fontsize=8)
    lines, names = ax.get_legend_handles_labels()
    if arms:
        right = ax.twinx()
        for name, speed in arms.items():
            right.plot(t, speed, linewidth=0.9, linestyle="--", label=name)
        right.set_ylabel("arm speed", fontsize=8)
        more, more_names = right.get_legend_handles_labels()
        lines, names = lines + more, names + more_names
    for c in cuts:
        ax.axvline(c, color="k", linewidth=0.8, alpha=0.6)
    ax.set_xlim(-0.5, episode.num_frames - 0.5)
    ax.set_xlabel(f"frame (cuts: {label})")
    ax.legend(lines, names, fontsize=7, loc="upper right", ncol=max(1, len(names)))
    ax.grid(axis="x", alpha=0.3)
