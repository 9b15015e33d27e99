"""Object-centric observation features shared by training (recorded frames) and acting (live sim).

An *observation* is a mapping with the privileged per-frame state of ``envs.record`` plus the
scene description and proprioception:

``ee_pose`` (7,) xyz + quat xyzw, ``gripper_open`` (bool/float), ``object_positions`` (K,3),
``object_quaternions`` (K,4), ``articulation_states`` (M,), ``held_object`` (int, -1 none),
``objects`` (K dicts with ``name``/``type``/``color``/``role``), ``articulations`` (M dicts with
``name``/``kind``/``closed``/``open``).

It is turned into *anchors*: every scene object plus the gripper itself and the world origin.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from envs.labeler import object_label
from rdd.data.episode import Episode

GRIPPER_ANCHOR = "the gripper"
WORLD_ANCHOR = "the table"
# held flag, articulation opening (0..1), fixture flag, has-articulation flag, rests on another
# object, carries another object (the last two tell a stacked block from a free one of the
# same colour: their heights differ by a plate's thickness only), and the height of what it
# carries (in units of STACK_UNIT metres): "place onto the stack" lands one block higher on a
# plate that carries two blocks than on one that carries one, and the plate alone cannot tell.
# Then, the same on every anchor, the held object's yaw relative to the hand (sin, cos; zeros when
# nothing is held): where a held shape must line up with a hole, the hand's turn depends on how the
# shape sits in the hand, which the hole's anchor cannot see otherwise.
STATE_DIM = 9
STACK_UNIT = 0.1
SUPPORT_MARGIN = 0.01  # metres of horizontal slack in the footprint test
OBS_KEYS = ("ee_pose", "gripper_open", "object_positions", "object_quaternions",
            "articulation_states", "held_object", "objects", "articulations")


@dataclass
class Anchors:
    """Per-anchor inputs of the keyframe network for one observation."""

    names: list[str]  # description texts (embedded with the instruction encoder)
    pos: np.ndarray  # (K+2, 3)
    yaw: np.ndarray  # (K+2,)
    state: np.ndarray  # (K+2, STATE_DIM)
    proprio: np.ndarray  # (8,) ee xyz, quat xyzw, gripper open


def yaw_of(quaternion: np.ndarray) -> np.ndarray:
    """Heading about world z of quaternions xyzw (..., 4): the angle of the body x axis."""
    q = np.asarray(quaternion, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def hand_yaw(quaternion: np.ndarray) -> np.ndarray:
    """Heading of the hand (xyzw quaternions (..., 4)): the finger-opening axis's heading + 90 deg.

    Equal to :func:`yaw_of` for a hand pointing down; unlike it, still defined for a hand pointing
    sideways (a drawer-handle grasp), whose body x axis is vertical and has no heading.
    """
    q = np.asarray(quaternion, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(1 - 2 * (x * x + z * z), 2 * (x * y - w * z)) + np.pi / 2


def _check(obs: Mapping[str, Any]) -> None:
    missing = [k for k in OBS_KEYS if k not in obs]
    if missing:
        raise KeyError(f"policy observation lacks {missing}; it needs {list(OBS_KEYS)}")


def anchors_from_observation(obs: Mapping[str, Any]) -> Anchors:
    """The anchors of one observation (see module docstring for the keys)."""
    _check(obs)
    objects = list(obs["objects"])
    arts = list(obs["articulations"])
    k = len(objects)
    opos = np.asarray(obs["object_positions"], dtype=np.float64).reshape(k, 3)
    oquat = np.asarray(obs["object_quaternions"], dtype=np.float64).reshape(k, 4)
    astate = np.asarray(obs["articulation_states"], dtype=np.float64).reshape(len(arts))
    held = int(obs["held_object"])
    ee = np.asarray(obs["ee_pose"], dtype=np.float64).reshape(7)
    grip = 1.0 if float(obs["gripper_open"]) >= 0.5 else 0.0

    state = np.zeros((k + 2, STATE_DIM))
    for i, o in enumerate(objects):
        state[i, 0] = 1.0 if i == held else 0.0
        state[i, 2] = 1.0 if o.get("role") == "fixture" else 0.0
        # An articulation belongs to the object whose name starts with its name
        # ("top_drawer" -> "top_drawer_handle", "red_button" -> "red_button").
        for m, a in enumerate(arts):
            if str(o.get("name", "")).startswith(str(a.get("name", "\0"))):
                span = float(a.get("open", 1.0)) - float(a.get("closed", 0.0))
                span = span if abs(span) > 1e-9 else 1.0
                state[i, 1] = (astate[m] - float(a.get("closed", 0.0))) / span
                state[i, 3] = 1.0
    on = _resting_on(opos, objects)
    sizes = _sizes(objects)
    for i in range(k):
        state[i, 4] = 1.0 if (on[i] >= 0 and i != held) else 0.0
        state[i, 5] = 1.0 if any(on[j] == i and j != held for j in range(k)) else 0.0
        state[i, 6] = _carried_height(i, on, held, opos, sizes) / STACK_UNIT
    state[k, 0] = 1.0 if held >= 0 else 0.0  # the gripper anchor: holding something
    if 0 <= held < k:
        in_hand = float(yaw_of(oquat[held]) - hand_yaw(ee[3:7]))
        state[:, 7], state[:, 8] = np.sin(in_hand), np.cos(in_hand)
    names = [object_label(o) for o in objects] + [GRIPPER_ANCHOR, WORLD_ANCHOR]
    pos = np.concatenate([opos, ee[None, :3], np.zeros((1, 3))])
    yaw = np.concatenate([yaw_of(oquat), [hand_yaw(ee[3:7])], [0.0]])
    return Anchors(names, pos, yaw, state, np.concatenate([ee, [grip]]))


def _sizes(objects: list[dict]) -> np.ndarray:
    return np.array([o.get("size", [0.0, 0.0, 0.0]) for o in objects], dtype=np.float64).reshape(-1, 3)


def _carried_height(i: int, on: list[int], held: int, pos: np.ndarray, sizes: np.ndarray) -> float:
    """How far the top of the unheld pile resting (directly or not) on object ``i`` rises above
    ``i``'s own top; 0 when nothing rests on it."""
    top = pos[i, 2] + 0.5 * sizes[i, 2]
    best = top
    frontier, seen = [i], {i}
    while frontier:
        parent = frontier.pop()
        for j, under in enumerate(on):
            if under == parent and j != held and j not in seen:
                seen.add(j)
                frontier.append(j)
                best = max(best, pos[j, 2] + 0.5 * sizes[j, 2])
    return float(best - top)


def _resting_on(pos: np.ndarray, objects: list[dict]) -> list[int]:
    """For each object, the index of the non-fixture object right under it (-1 for none)."""
    sizes = _sizes(objects)
    out = []
    for i in range(len(objects)):
        best, best_z = -1, -np.inf
        for j, o in enumerate(objects):
            if j == i or o.get("role") == "fixture":
                continue
            inside = np.all(np.abs(pos[i, :2] - pos[j, :2]) <= 0.5 * sizes[j, :2] + SUPPORT_MARGIN)
            gap = pos[i, 2] - pos[j, 2]
            # Directly on top: the centres are at most the two half-heights (+2 cm) apart.
            if inside and 0 < gap <= 0.5 * (sizes[i, 2] + sizes[j, 2]) + 0.02 and pos[j, 2] > best_z:
                best, best_z = j, pos[j, 2]
        out.append(best)
    return out


def observation_at(episode: Episode, t: int) -> dict[str, Any]:
    """The policy observation of frame ``t`` of a recorded episode with a privileged record."""
    priv = episode.meta.get("privileged")
    if priv is None or "object_positions" not in priv:
        raise ValueError(f"episode {episode.name!r} has no privileged record; the policy needs it")
    if episode.ee_poses is None or episode.gripper_open is None:
        raise ValueError(f"episode {episode.name!r} lacks ee_poses or gripper_open")
    return {
        "ee_pose": episode.ee_poses[t],
        "gripper_open": float(episode.gripper_open[t]),
        "object_positions": priv["object_positions"][t],
        "object_quaternions": priv["object_quaternions"][t],
        "articulation_states": priv["articulation_states"][t],
        "held_object": int(priv["held_object"][t]),
        "objects": episode.meta.get("objects", []),
        "articulations": episode.meta.get("articulations", []),
    }
