"""The RLBench keyframe rule against a transcription of PerAct's list-of-observations loop."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rdd.data.episode import Episode
from rdd.decomposers.expert import ExpertDecomposer, keypoint_discovery


def reference(demo, stopping_delta=0.1):
    """PerAct's _keypoint_discovery over observation objects (Python list indexing and all)."""

    def is_stopped(i, obs, buf):
        next_is_not_final = i == (len(demo) - 2)
        no_change = i < (len(demo) - 2) and (
            obs.gripper_open == demo[i + 1].gripper_open
            and obs.gripper_open == demo[i - 1].gripper_open
            and demo[i - 2].gripper_open == demo[i - 1].gripper_open
        )
        small = np.allclose(obs.joint_velocities, 0, atol=stopping_delta)
        return buf <= 0 and small and (not next_is_not_final) and no_change

    kps, prev, buf = [], demo[0].gripper_open, 0
    for i, obs in enumerate(demo):
        stopped = is_stopped(i, obs, buf)
        buf = 4 if stopped else buf - 1
        if i != 0 and (obs.gripper_open != prev or i == len(demo) - 1 or stopped):
            kps.append(i)
        prev = obs.gripper_open
    if len(kps) > 1 and (kps[-1] - 1) == kps[-2]:
        kps.pop(-2)
    return kps


@settings(max_examples=150, deadline=None)
@given(
    t=st.integers(1, 40),
    seed=st.integers(0, 100_000),
    p_flip=st.sampled_from([0.0, 0.1, 0.4]),
    p_still=st.sampled_from([0.2, 0.6, 0.9]),
)
def test_matches_reference_loop(t, seed, p_flip, p_still):
    rng = np.random.default_rng(seed)
    grip = np.cumsum(rng.random(t) < p_flip) % 2
    vel = rng.normal(scale=0.5, size=(t, 3))
    vel[rng.random(t) < p_still] *= 0.05
    demo = [SimpleNamespace(gripper_open=float(g), joint_velocities=v) for g, v in zip(grip, vel, strict=True)]
    assert keypoint_discovery(grip, vel) == reference(demo)


def test_hand_made_case():
    # Moving, stop at 5..7 (keyframe at 5 only: 4-frame buffer), close at 10, move to the end.
    vel = np.ones((16, 2))
    vel[5:8] = 0.0
    grip = np.ones(16)
    grip[10:] = 0.0
    assert keypoint_discovery(grip, vel) == [5, 10, 15]


def test_real_rlbench_episodes(real_data):
    DATA = real_data("rlbench")
    from rdd.data.rlbench import load_episodes

    eps = load_episodes(DATA)
    assert len(eps) == 6
    by_name = {e.name: e for e in eps}
    dec = ExpertDecomposer()
    assert dec.decompose(by_name["episode0"]).keyframes == [70, 85, 124]
    for e in eps:
        demo = [SimpleNamespace(gripper_open=g, joint_velocities=v)
                for g, v in zip(e.gripper_open, e.joint_velocities, strict=True)]
        ks = dec.decompose(e).keyframes
        assert ks == reference(demo) and len(ks) == 3 and ks[-1] == e.num_frames - 1


def test_needs_signals():
    ep = Episode(name="x", views={}, gripper_open=np.ones(5))
    with pytest.raises(ValueError, match="joint_velocities nor ee_poses"):
        ExpertDecomposer().decompose(ep)
    ep = Episode(name="x", views={}, joint_velocities=np.ones((5, 2)))
    with pytest.raises(ValueError, match="gripper_open"):
        ExpertDecomposer().decompose(ep)
    poses = np.zeros((12, 7))
    poses[:, 0] = np.minimum(np.arange(12), 5)
    ep = Episode(name="x", views={}, gripper_open=np.ones(12), ee_poses=poses)
    out = ExpertDecomposer().decompose(ep)
    assert out.meta["velocity_source"] == "ee" and out.segments[-1] == (out.segments[-1][0], 12)
    assert out.keyframes[0] == 6  # first still frame after the motion stops


def test_scale_aware_stop_test_counts_each_rest_once():
    """30 fps, noisy joint velocities in rad/s: moving at ~1 rad/s, resting 1 s at frames 60-89 and
    0.5 s at 150-164, the gripper closing at 120. RLBench's absolute rule fires every 5 frames of a
    rest; the scale-aware test gives exactly one keyframe per rest, the gripper change and the end."""
    rng = np.random.default_rng(0)
    t, fps = 210, 30.0
    v = 1.0 + 0.2 * rng.standard_normal((t, 7))
    v[60:90] = 0.02 * rng.standard_normal((30, 7))
    v[150:165] = 0.02 * rng.standard_normal((15, 7))
    grip = np.ones(t)
    grip[120:] = 0.0
    ep = Episode(name="real", views={}, gripper_open=grip, joint_velocities=v, meta={"fps": fps})
    out = ExpertDecomposer().decompose(ep)
    assert out.meta["stop_test"] == "scale"
    # the smoothing window (3 frames) may move a rest's first frame by one
    assert len(out.keyframes) == 4
    assert abs(out.keyframes[0] - 60) <= 1 and out.keyframes[1] == 120 and abs(out.keyframes[2] - 150) <= 1
    assert out.keyframes[3] == t - 1
    absolute = ExpertDecomposer(stop_test="absolute").decompose(ep).keyframes
    assert len([k for k in absolute if 60 <= k < 90]) == 6  # 60, 65, ..., 85
    # The same motion at 60 fps (twice the frames) gives the same cuts in seconds.
    ep2 = Episode(name="real60", views={}, gripper_open=np.repeat(grip, 2), joint_velocities=np.repeat(v, 2, axis=0),
                  meta={"fps": 2 * fps})
    k2 = ExpertDecomposer().decompose(ep2).keyframes
    assert len(k2) == 4 and abs(k2[0] - 120) <= 3 and k2[1] == 240  # window 6 frames: within 3


def test_expert_options_are_checked():
    for kwargs, match in [({"stopping_delta": -1}, "stopping_delta must be >= 0"),
                          ({"stop_test": "magic"}, "stop_test must be one of"),
                          ({"stopping_fraction": 1.5}, "stopping_fraction must be >= 0.0 and <= 1.0"),
                          ({"velocity_source": "x"}, "velocity_source")]:
        with pytest.raises(ValueError, match=match):
            ExpertDecomposer(**kwargs)
    ep = Episode(name="x", views={}, gripper_open=np.ones(5), joint_velocities=np.ones((5, 2)))
    with pytest.raises(ValueError, match="declares no fps"):
        ExpertDecomposer(stop_test="scale").decompose(ep)
