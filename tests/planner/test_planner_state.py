"""The planner reads the robot's proprioceptive state, as the paper's pi(l_t | s_t, o_t, l_{t-1}, L):
stated in its prompt, learned from the demonstrations' recorded hand pose and gripper, and deciding
the answer where the image, goal and previous instruction leave it open."""

import numpy as np
import pytest
import torch

pytest.importorskip("peft")

from planner.config import PlannerConfig  # noqa: E402
from planner.dataset import PlannerExample, examples_from_episode  # noqa: E402
from planner.planner import VLMPlanner  # noqa: E402
from planner.prompts import robot_state, user_prompt  # noqa: E402
from planner.train import pretrain_base  # noqa: E402
from rdd.data.episode import Episode  # noqa: E402

GOAL = "put the block in the bin"
PREVIOUS = "reach for the block"
OPEN = {"ee_pose": np.array([0.4, 0.0, 0.10, 0, 0, 0, 1.0]), "gripper_open": np.array([1.0])}
CLOSED = {"ee_pose": np.array([0.4, 0.0, 0.10, 0, 0, 0, 1.0]), "gripper_open": np.array([0.0])}


def test_the_prompt_states_the_gripper_and_the_hand_height():
    assert robot_state(OPEN["ee_pose"], OPEN["gripper_open"]) == "the gripper is open and the hand is 10 cm high"
    assert robot_state([0, 0, 0.257], 0.0) == "the gripper is closed and the hand is 26 cm high"
    prompt = user_prompt(GOAL, PREVIOUS, state=robot_state(CLOSED["ee_pose"], 0))
    assert "The robot: the gripper is closed and the hand is 10 cm high." in prompt
    assert "The robot" not in user_prompt(GOAL, PREVIOUS)


def test_examples_carry_the_state_of_their_frame():
    t = 6
    ee = np.zeros((t, 7))
    ee[:, 2] = np.linspace(0.1, 0.35, t)
    grip = np.array([1, 1, 1, 0, 0, 0], float)
    ep = Episode(name="e", views={"front": np.zeros((t, 8, 8, 3), np.uint8)}, goal=GOAL, task="toy",
                 ee_poses=ee, gripper_open=grip, segments=[(0, 3), (3, 6)], instructions=["grasp", "lift"])
    ex = examples_from_episode(ep)
    assert [e.state for e in ex] == [robot_state(ee[0], 1), robot_state(ee[3], 0)]
    assert all(e.state is None for e in examples_from_episode(ep, read_state=False))


def test_only_the_state_changes_and_the_answer_follows_it(tmp_path):
    """Same image, goal and previous instruction; the gripper open says grasp, closed says lift."""
    torch.manual_seed(0)
    image = np.full((64, 64, 3), 200, np.uint8)
    examples = []
    for state, target in ((OPEN, "grasp the block"), (CLOSED, "lift the block")):
        for height in (0.08, 0.10, 0.12):
            pose = state["ee_pose"].copy()
            pose[2] = height
            examples.append(PlannerExample(image=image, goal=GOAL, previous_instruction=PREVIOUS, target=target,
                                           state=robot_state(pose, state["gripper_open"])))
    cfg = PlannerConfig(kind="tiny_llava", vocab_size=300, max_new_tokens=8,
                        pretrain=dict(lr=5e-3, epochs=40, batch_size=6, warmup_ratio=0.1))
    base = pretrain_base(cfg, examples, tmp_path / "base", progress=False)
    planner = VLMPlanner(cfg, base)
    assert planner.next_instruction(image, GOAL, PREVIOUS, state=OPEN) == "grasp the block"
    assert planner.next_instruction(image, GOAL, PREVIOUS, state=CLOSED) == "lift the block"
    blind = VLMPlanner(PlannerConfig(**{**cfg.to_dict(), "read_state": False}), base)
    assert blind.next_instruction(image, GOAL, PREVIOUS, state=OPEN) == blind.next_instruction(
        image, GOAL, PREVIOUS, state=CLOSED)
