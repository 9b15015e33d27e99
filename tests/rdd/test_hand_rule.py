"""The expert rule on hands and arms: synthetic hand signals whose events are known by construction."""

from __future__ import annotations

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.data.hand_events import hand_moves, sample_period, turning_points
from rdd.decomposers.expert import ExpertDecomposer

FPS = 30


def ramp(t: int, plan: list[tuple[int, float, int]], start: float) -> np.ndarray:
    """A level that starts at ``start`` and moves linearly to ``value`` over ``duration`` frames centred on
    ``frame`` for each (frame, value, duration): the known event frames are the ramps' midpoints."""
    x = np.full(t, start)
    level = start
    for frame, value, duration in plan:
        a, b = frame - duration // 2, frame + duration // 2
        x[a:b] = level + (value - level) * (np.arange(b - a) + 0.5) / (b - a)
        x[b:] = value
        level = value
    return x


def hold(x: np.ndarray, period: int) -> np.ndarray:
    """Sample-and-hold every ``period`` frames (a hand updated slower than the cameras)."""
    return x[(np.arange(len(x)) // period) * period]


def g1_like(t=300, period=3, flicker=0.03, rest=None, seed=0) -> tuple[Episode, list[int]]:
    """A right hand that opens, closes on an object, opens and closes again; an idle left hand; the arm
    moves throughout (or rests over ``rest``). Returns the episode and the right hand's event frames."""
    events = [40, 110, 220, 270]
    # Drawn over 300 frames; a shorter t ends the recording part way through.
    right = ramp(300, [(40, 0.8, 24), (110, 0.5, 20), (220, 0.8, 30), (270, 0.4, 16)], 0.4)[:t]
    rng = np.random.default_rng(seed)
    # While it holds the object the hand hovers at the reader's threshold: 0.5 +- flicker.
    right[125:205] += flicker * np.sign(np.sin(np.arange(80) * 1.3))
    left = 0.7 + 0.01 * rng.standard_normal(t)
    levels = np.stack([hold(left, period), hold(right, period)], axis=1)
    vel = 0.5 + 0.3 * np.abs(np.sin(np.arange(t) / 15.0))[:, None] * np.ones((t, 14))
    if rest is not None:
        vel[rest[0]:rest[1]] = 0.0
    ep = Episode(name="g1", views={}, gripper_open=(levels > 0.5).mean(axis=1), joint_velocities=vel,
                 meta={"fps": FPS, "hand_levels": levels, "gripper": {"indices": [list(range(14, 20)),
                       list(range(20, 26))], "sides": ["left", "right"], "open_above": True}})
    return ep, events


def test_turning_points_and_moves_of_a_known_signal():
    x = ramp(100, [(30, 1.0, 10), (70, 0.0, 20)], 0.0)
    x[45:55] += 0.04 * np.sign(np.sin(np.arange(10)))  # wiggles smaller than delta are no moves
    pts = turning_points(x, 0.1)
    assert len(pts) == 3 and pts[0] <= 25 and 35 <= pts[1] <= 60 and pts[2] >= 80
    moves = hand_moves(x, 0.1)
    assert [m.opens for m in moves] == [True, False]
    assert [abs(m.frame - e) <= 1 for m, e in zip(moves, (30, 70), strict=True)] == [True, True]
    # 10 %-90 % of a linear ramp of d frames takes 0.8 d.
    assert [m.duration for m in moves] == pytest.approx([8, 16], abs=1.5)
    assert turning_points(np.full(20, 0.5), 0.1) == [] and hand_moves(np.zeros(0), 0.1) == []
    assert sample_period(hold(x, 4)) == 4 and sample_period(x) == 1


@pytest.mark.parametrize("period", [1, 3, 4])
def test_hand_rule_cuts_at_each_event_and_ignores_flicker(period):
    ep, events = g1_like(period=period)
    d = ExpertDecomposer().decompose(ep)
    assert d.meta["rule"] == "hands"
    cuts = [s for s, _ in d.segments[1:]]
    # One cut per event, each within a sample period (+1 for the ramp's rounding) of its midpoint;
    # the hand hovering at 0.5 +- 0.03 while it holds the object adds none.
    assert len(cuts) == len(events)
    assert all(abs(c - e) <= period + 1 for c, e in zip(cuts, events, strict=True)), cuts
    assert d.meta["min_frames"] == 2 * period
    # The measured event timescale is the median 10-90 % time of the moves: 0.8 x (16, 20, 24, 30).
    assert abs(d.meta["event_timescale"] - 0.8 * 22) <= period + 1


def test_a_long_arm_rest_cuts_a_short_one_does_not():
    ep, events = g1_like(rest=(150, 190))  # 40 frames, longer than the event timescale (about 18)
    d = ExpertDecomposer().decompose(ep)
    assert len(d.meta["arm_cuts"]) == 1 and 150 <= d.meta["arm_cuts"][0] < 190
    ep, _ = g1_like(rest=(150, 160))
    assert ExpertDecomposer().decompose(ep).meta["arm_cuts"] == []


def test_no_segment_under_two_hand_updates_even_at_an_event():
    """A close that the recording cuts off leaves no segment of 4 frames (its midpoint is 4 frames from the end)."""
    ep, _ = g1_like(t=270, period=3)
    segs = ExpertDecomposer().decompose(ep).segments
    assert min(e - s for s, e in segs) >= 6 and segs[-1][1] == 270
    assert len(segs) == 4  # the cut-off close is merged into the last segment


def test_single_gripper_keeps_the_keyframe_rule_and_rule_hands_is_an_option():
    ep, _ = g1_like()
    single = Episode(name="one", views={}, gripper_open=ep.gripper_open, joint_velocities=ep.joint_velocities,
                     meta={"fps": FPS, "hand_levels": ep.meta["hand_levels"][:, :1],
                           "gripper": {"indices": [[3]], "open_above": True}})
    assert ExpertDecomposer().decompose(single).meta["stop_test"] == "scale"
    assert ExpertDecomposer(rule="keyframes").decompose(ep).meta["stop_test"] == "scale"
    forced = ExpertDecomposer(rule="hands").decompose(single)
    assert forced.meta["rule"] == "hands"
    with pytest.raises(ValueError, match="rule"):
        ExpertDecomposer(rule="fingers")
    with pytest.raises(ValueError, match="hand_delta"):
        ExpertDecomposer(hand_delta=0)
