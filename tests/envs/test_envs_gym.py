"""Gymnasium environment: spaces, seeded reset, expert replay, failed-motion flags."""

from __future__ import annotations

import numpy as np
import pytest

from envs.gym_env import RLBenchStyleEnv


@pytest.fixture(scope="module")
def env():
    e = RLBenchStyleEnv("open_drawer", render_images=False)
    yield e
    e.close()


def _state(obs):
    return {k: v.copy() for k, v in obs.items() if not k.endswith("_rgb")}


def test_reset_is_deterministic_per_seed_and_variation(env):
    a, info_a = env.reset(seed=7, options={"variation": 2})
    b, info_b = env.reset(seed=7, options={"variation": 2})
    assert info_a["goal"] == info_b["goal"] == "open the bottom drawer"
    for k in _state(a):
        np.testing.assert_array_equal(a[k], b[k])
    c, _ = env.reset(seed=8, options={"variation": 2})
    assert not np.allclose(a["object_positions"], c["object_positions"])
    assert env.observation_space.contains(a)


def test_reset_matches_the_expert_scene(env, demo):
    res = demo("open_drawer", 1)
    obs, info = env.reset(seed=1)
    assert info["goal"] == res.episode.goal
    np.testing.assert_allclose(obs["object_positions"], res.privileged["object_positions"][0], atol=1e-6)


def test_replaying_expert_waypoints_succeeds(env, demo):
    res = demo("open_drawer", 1)
    env.reset(seed=1)
    terminated = False
    for wp in res.episode.meta["waypoints"]:
        action = np.array([*wp["position"], *wp["quaternion"], float(wp["gripper_open"])], dtype=np.float32)
        assert env.action_space.contains(action)
        obs, reward, terminated, truncated, info = env.step(action)
        assert not info["motion_failed"], info
        assert env.observation_space.contains(obs)
    assert terminated and reward == 1.0 and info["success"]


def test_unreachable_pose_sets_flag_without_raising(env):
    env.reset(seed=3)
    obs, reward, terminated, truncated, info = env.step(np.array([1.4, 0.9, 1.1, 1, 0, 0, 0, 1.0]))
    assert info["motion_failed"] and info["failure"] == "unreachable"
    assert reward == 0.0 and not terminated


def test_driving_into_the_table_sets_collision_flag(env):
    env.reset(seed=3)
    down = np.array([0.0, 1.0, 0.0, 0.0])  # xyzw: hand pointing down
    obs, _, _, _, info = env.step(np.array([0.45, 0.0, -0.04, *down, 1.0]))
    assert info["motion_failed"] and info["failure"] in ("collision", "timeout"), info
    assert obs["ee_pose"][2] > -0.01  # the hand stays on top of the table


def test_bad_action_is_a_clear_error(env):
    env.reset(seed=3)
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(5))


def test_truncates_after_max_steps():
    e = RLBenchStyleEnv("turn_tap", render_images=False, max_steps=1)
    try:
        obs, _ = e.reset(seed=0)
        _, _, terminated, truncated, _ = e.step(np.concatenate([obs["ee_pose"], [1.0]]))
        assert truncated and not terminated
    finally:
        e.close()
