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


def draw_signals(ax, episode: Episode, cuts: tuple[str, Sequence[int]],
                 truth: tuple[str, Sequence[int]] | None = None) -> None:
    """Hand levels (left axis) and arm speeds (right axis, dashed) of ``episode``; ``cuts`` (a row's
    label and cut frames) as solid black lines, ``truth``'s as dashed red ones, as the timeline
    above draws them. The legend sits beside the axes, where it covers no signal."""
    from matplotlib.lines import Line2D

    hands, arms = episode_signals(episode)
    t = np.arange(episode.num_frames)
    for name, level in hands.items():
        ax.plot(t, level, linewidth=1.2, label=name)
    ax.set_ylabel("hand level\n(1 = open)", fontsize=8)
    lines, names = ax.get_legend_handles_labels()
    if arms:
        right = ax.twinx()
        for name, speed in arms.items():
            right.plot(t, speed, linewidth=0.9, linestyle="--", label=name)
        # max |joint velocity| over the arm's joints: the reader's finite differences x fps of joint
        # angles, so radians per second when the data says its fps
        unit = "rad/s" if episode.meta.get("fps") else "per frame"
        right.set_ylabel(f"arm speed, fastest joint\n({unit})", fontsize=8)
        right.set_ylim(bottom=0)
        more, more_names = right.get_legend_handles_labels()
        lines, names = lines + more, names + more_names
    drawn = [(cuts, "k", "-")] + ([(truth, "#d62728", (0, (3, 2)))] if truth else [])
    for (label, frames), colour, style in drawn:
        for c in frames:
            ax.axvline(c - 0.5, color=colour, linestyle=style, linewidth=0.9, alpha=0.8)
        lines.append(Line2D([], [], color=colour, linestyle=style))
        names.append(f"cuts: {label}")
    ax.set_xlim(-0.5, episode.num_frames - 0.5)
    ax.set_xlabel("frame")
    ax.legend(lines, names, fontsize=7, loc="upper left", bbox_to_anchor=(1.07, 1.0), frameon=False)
    ax.grid(axis="x", alpha=0.3)
