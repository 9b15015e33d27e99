"""The signals labeler on synthetic hand and arm signals whose events are known by construction."""

from __future__ import annotations

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.labelers.signals import SignalsLabeler


def two_handed(t: int = 120) -> Episode:
    """Left hand closes at 30 (frames 25-35), right hand closes at 30 too and opens at 90; the left arm
    moves over frames 0-59 only, the right arm over 0-119."""
    left = np.where(np.arange(t) < 30, 0.9, 0.3)
    right = np.where((np.arange(t) < 30) | (np.arange(t) >= 90), 0.8, 0.2)
    vel = np.zeros((t, 4))
    vel[:60, :2] = 1.0  # left arm: columns 0-1
    vel[:, 2:] = 1.0  # right arm: columns 2-3
    vel += 0.001 * np.random.default_rng(0).standard_normal(vel.shape)  # sensor noise is not motion
    return Episode(name="two", views={}, joint_velocities=vel,
                   meta={"fps": 10, "hand_levels": np.stack([left, right], axis=1),
                         "gripper": {"sides": ["left", "right"], "open_above": True},
                         "arm_sides": {"left": [0, 1], "right": [2, 3]}})


def test_names_hands_and_arms():
    lab = SignalsLabeler()
    ep = two_handed()
    assert lab.label_all(ep, [(0, 30), (30, 60), (60, 90), (90, 120)]) == [
        "both arms move and both hands close",  # the change at 30 completes this segment
        "both arms move",
        "right arm moves and right hand opens",
        "right arm moves",
    ]
    # A segment that holds the open of one hand only, while no arm moves.
    still = Episode(name="s", views={}, joint_velocities=np.zeros((120, 4)), meta=ep.meta)
    assert lab.label(still, (60, 100)) == "right hand opens"
    assert lab.label(still, (0, 20)) == "hold still"


def test_single_gripper_without_sides_and_lower_means_open():
    g = np.repeat([1.0, 0.0, 1.0], 10)
    ep = Episode(name="g", views={}, gripper_open=g, joint_velocities=np.ones((30, 3)))
    assert SignalsLabeler().label_all(ep, [(0, 15), (15, 30)]) == [
        "arm moves and gripper closes", "arm moves and gripper opens"]
    # A dataset whose gripper value rises as it closes (open_above false).
    ep = Episode(name="h", views={}, joint_velocities=np.zeros((30, 3)),
                 meta={"hand_levels": (1 - g)[:, None], "gripper": {"open_above": False}})
    assert SignalsLabeler().label(ep, (0, 15)) == "gripper closes"


def test_no_signals_and_bad_options_are_errors():
    with pytest.raises(ValueError, match="no hand, gripper or joint signals.*--fallback-instruction"):
        SignalsLabeler().label(Episode(name="bare", views={}), (0, 1))
    with pytest.raises(ValueError, match="moving_fraction"):
        SignalsLabeler(moving_fraction=2)
