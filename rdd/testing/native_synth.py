"""Synthetic native episodes for tests and benchmarks: three sub-tasks of drifting colours, or noise.

Each sub-task moves the scene colour from one of three targets (red, green, blue) to the next, with a
little per-pixel noise; the gripper is closed during the second sub-task, so the expert rule cuts
where the gripper state changes. Two views: ``front`` and its mirror image ``wrist``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

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


def write_noise_episodes(root: str | Path, count: int, gripper: Sequence[float], per_part: int,
                         size: int = 8) -> Path:
    """``count`` native episodes ep0.. of uniform-noise frames (episode k from seed k) under ``root``;
    the gripper holds each value of ``gripper`` for ``per_part`` frames, so the expert rule cuts there."""
    from rdd.data.native import save_episode

    root = Path(root)
    t = len(gripper) * per_part
    for k in range(count):
        frames = np.random.default_rng(k).integers(0, 255, size=(t, size, size, 3), dtype=np.uint8)
        save_episode(Episode(name=f"ep{k}", views={"front": frames, "wrist": frames[:, ::-1].copy()},
                             gripper_open=np.repeat(np.asarray(gripper, dtype=float), per_part),
                             joint_velocities=np.ones((t, 7)), goal="toy", task="toy"), root / f"ep{k}")
    return root
