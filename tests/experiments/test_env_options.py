"""The env config group reaches demo generation and evaluation alike."""

from pathlib import Path

import pytest
from omegaconf import OmegaConf

pytest.importorskip("pybullet")


def _env(**over):
    base = {"_target_": "envs.gym_env.RLBenchStyleEnv", "_partial_": True, "image_size": 32,
            "render_images": True, "max_steps": 30, "ticks_per_frame": 12, "motion_timeout": 3.0}
    return OmegaConf.create({**base, **over})


def test_demos_are_recorded_with_the_envs_physics(tmp_path: Path):
    from experiments.run import components as comp
    from rdd.data.native import load_episode

    # 24 ticks of 240 Hz physics per frame: a 10 Hz recording, as the env steps in evaluation
    (d,) = comp.episodes_for(_env(ticks_per_frame=24), "turn_tap", "train", 1, tmp_path)
    slow = load_episode(d)
    (d,) = comp.episodes_for(_env(), "turn_tap", "train", 1, tmp_path / "default")
    fast = load_episode(d)
    assert slow.meta["frame_rate"] == 10.0 and fast.meta["frame_rate"] == 20.0
    assert slow.num_frames < fast.num_frames  # the same motions, recorded half as often
    assert slow.meta["image_size"] == [32, 32]


def test_demo_key_options_leave_out_only_the_loops_step_budget():
    from experiments.run import components as comp

    opts = comp.demo_env_options(_env())
    assert set(opts) == {"image_size", "render_images", "ticks_per_frame", "motion_timeout"}
    assert comp.demo_env_options(_env(max_steps=5)) == opts
    with pytest.raises(ValueError, match=r"env: option\(s\) \['fps'\]"):
        comp.demo_env_options(_env(fps=10))
