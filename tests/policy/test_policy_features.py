"""Per-anchor state: what rests on what, and how high the pile an object carries rises."""

from __future__ import annotations

import numpy as np

from policy.features import STACK_UNIT, anchors_from_observation

PLATE_TOP = 0.76
BLOCK = 0.05


def _obs(held: int = -1) -> dict:
    # plate, a block on it, a block on that block, a free block on the table
    objects = [
        {"name": "plate", "type": "plate", "color": "grey", "size": [0.1, 0.1, 0.01], "role": "target"},
        {"name": "red_block_0", "type": "block", "color": "red", "size": [BLOCK] * 3, "role": "target"},
        {"name": "red_block_1", "type": "block", "color": "red", "size": [BLOCK] * 3, "role": "target"},
        {"name": "red_block_2", "type": "block", "color": "red", "size": [BLOCK] * 3, "role": "target"},
    ]
    pos = [[0.5, 0.0, PLATE_TOP - 0.005],
           [0.501, 0.002, PLATE_TOP + BLOCK / 2],
           [0.499, -0.001, PLATE_TOP + 1.5 * BLOCK],
           [0.4, 0.2, PLATE_TOP - 0.01 + BLOCK / 2]]
    return {"ee_pose": np.array([0.3, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]), "gripper_open": 1.0,
            "object_positions": np.array(pos), "object_quaternions": np.tile([0, 0, 0, 1.0], (4, 1)),
            "articulation_states": np.zeros(0), "held_object": held, "objects": objects,
            "articulations": []}


def test_carried_height_counts_the_whole_pile_in_block_heights():
    state = anchors_from_observation(_obs()).state
    # the plate carries two blocks: the pile's top is 2 block heights above the plate's top
    assert np.isclose(state[0, 6] * STACK_UNIT, 2 * BLOCK, atol=1e-6)
    assert np.isclose(state[1, 6] * STACK_UNIT, BLOCK, atol=1e-6)
    assert state[2, 6] == 0.0 and state[3, 6] == 0.0
    # rests-on / carries flags agree with the geometry
    assert list(state[:4, 4]) == [0, 1, 1, 0] and list(state[:4, 5]) == [1, 1, 0, 0]


def test_a_held_block_is_not_part_of_the_pile():
    state = anchors_from_observation(_obs(held=2)).state
    assert np.isclose(state[0, 6] * STACK_UNIT, BLOCK, atol=1e-6)
    assert state[1, 6] == 0.0


def test_every_anchor_sees_how_the_held_object_sits_in_the_hand():
    obs = _obs(held=3)
    turn = 0.3
    obs["object_quaternions"][3] = [0.0, 0.0, np.sin(turn / 2), np.cos(turn / 2)]  # yaw 0.3 rad
    state = anchors_from_observation(obs).state  # the hand's yaw is 0 (a half turn about x)
    assert np.allclose(state[:, 7], np.sin(turn)) and np.allclose(state[:, 8], np.cos(turn))
    free = anchors_from_observation(_obs(held=-1)).state
    assert np.all(free[:, 7:9] == 0.0)


def test_hand_heading_is_defined_for_a_sideways_grasp():
    from envs.poses import gripper_quat, top_down_quat
    from policy.features import hand_yaw, yaw_of

    for psi in np.linspace(-3.0, 3.0, 7):  # pointing down: the body x axis's heading, as before
        q = top_down_quat(psi)
        assert np.isclose(np.angle(np.exp(1j * (hand_yaw(q) - yaw_of(q)))), 0.0, atol=1e-9)
    # Pointing sideways along +x, fingers along +y, tilted by up to 1 degree: the body x axis is
    # (nearly) vertical, so its heading swings; the hand's stays pi (fingers' heading + 90 deg).
    headings = []
    for tilt in np.radians([-1.0, -0.1, 0.0, 0.1, 1.0]):
        approach = np.array([np.cos(tilt), 0.0, np.sin(tilt)])
        headings.append(float(hand_yaw(gripper_quat(approach, np.array([0.0, 1.0, 0.0])))))
    assert np.allclose(np.cos(headings), -1.0, atol=1e-6)
