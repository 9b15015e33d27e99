"""Synthetic native episodes for tests and benchmarks: three sub-tasks of drifting colours.

Each sub-task moves the scene colour from one of three targets (red, green, blue) to the next, with a
little per-pixel noise; the gripper is closed during the second sub-task, so the expert rule cuts
where the gripper state changes. Two views: ``front`` and its mirror image ``wrist``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.data.episode import Episode

COLOURS = np.array([[230, 30, 30], [30, 230, 30], [30, 30, 230]], dtype=float)


def colour_episode(name: str, lengths: Sequence[int], seed: int, size: int = 16) -> Episode:
    """An episode of ``len(lengths)`` sub-tasks of ``lengths[j]`` frames (``size`` x ``size`` pixels)."""
    rng = np.random.default_rng(seed)
    t = sum(lengths)
    frames = np.zeros((t, size, size, 3), dtype=np.uint8)
    grip, start = np.ones(t), 0
    for j, n in enumerate(lengths):
        a, b = COLOURS[j % 3], COLOURS[(j + 1) % 3]
        for i in range(n):
            c = a + (b - a) * i / max(n - 1, 1)
            frames[start + i] = np.clip(c + rng.normal(0, 3, size=(size, size, 3)), 0, 255)
        if j == 1:
            grip[start:start + n] = 0.0
        start += n
    return Episode(name=name, views={"front": frames, "wrist": frames[:, ::-1].copy()}, gripper_open=grip,
                   joint_velocities=np.ones((t, 7)), goal="move the colours", task="toy")
