"""Task interface: scene building, goal text, success detector and scripted expert waypoints."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from envs.poses import top_down_quat
from envs.record import ArticulationInfo, ObjectInfo
from envs.scene import Scene

HOME_FINGER_YAW = -np.pi / 4  # middle of the finger yaws joint 7 can reach with the hand down


@dataclass
class Waypoint:
    """One expert target: grasp-point pose, gripper state at arrival, and the segment's instruction."""

    position: np.ndarray
    quaternion: np.ndarray
    gripper_open: bool
    instruction: str


@dataclass
class SceneObject:
    """A tracked object: its static description and where it lives in the simulation."""

    info: ObjectInfo
    body: int
    link: int = -1


@dataclass
class Articulation:
    """A tracked joint: its description, body/joint ids, and the sign mapping joint value -> state."""

    info: ArticulationInfo
    body: int
    joint: int
    sign: float = 1.0


def grasp_yaw(object_yaw: float, symmetry: float = np.pi / 2) -> float:
    """The yaw equivalent to ``object_yaw`` (mod ``symmetry``) closest to the home finger yaw."""
    k = np.round((HOME_FINGER_YAW - object_yaw) / symmetry)
    return float(object_yaw + k * symmetry)


def yaw_of(quaternion) -> float:
    """Heading (rotation about world z) of a quaternion xyzw."""
    x, y, z, w = quaternion
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def finger_yaw(hand_quaternion) -> float:
    """Finger-opening direction (yaw) of a hand orientation."""
    import pybullet as pb

    m = np.array(pb.getMatrixFromQuaternion(list(hand_quaternion))).reshape(3, 3)
    return float(np.arctan2(m[1, 1], m[0, 1]))


def sample_positions(rng: np.random.Generator, n: int, x_range, y_range, min_dist: float,
                     avoid=(), tries: int = 2000) -> list[np.ndarray]:
    """``n`` xy positions in the box, at least ``min_dist`` apart and from ``avoid``."""
    out: list[np.ndarray] = []
    for _ in range(tries):
        if len(out) == n:
            return out
        cand = np.array([rng.uniform(*x_range), rng.uniform(*y_range)])
        if all(np.linalg.norm(cand - np.asarray(o)[:2]) >= min_dist for o in [*out, *avoid]):
            out.append(cand)
    raise RuntimeError(f"could not place {n} objects {min_dist} m apart in {x_range} x {y_range}")


class Task(ABC):
    """One RLBench-style task. Subclasses set ``name``, ``variations`` and implement the hooks."""

    name: ClassVar[str] = ""
    pretraining: ClassVar[bool] = False  # held out of evaluation averages (planner pretraining)
    order: ClassVar[int] = 100  # place in the suite's listings (the paper's tables order its tasks 1-7)
    description: ClassVar[str] = ""

    def __init__(self) -> None:
        self.scene: Scene | None = None
        self.objects: list[SceneObject] = []
        self.articulations: list[Articulation] = []
        self.variation: int = 0
        self.params: dict[str, Any] = {}

    # -- to implement ------------------------------------------------------------------
    @abstractmethod
    def variations(self) -> list[dict[str, Any]]:
        """All variations' parameters (e.g. ``[{"drawer": "top"}, ...]``)."""

    @abstractmethod
    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Create the task's bodies for ``self.params`` with random placement from ``rng``."""

    @abstractmethod
    def goal(self) -> str:
        """The language goal, which states the variation."""

    @abstractmethod
    def expert(self) -> Iterator[Waypoint]:
        """Scripted waypoints; a generator so later waypoints can read the state reached."""

    @abstractmethod
    def success(self) -> bool:
        """The success detector on the current simulation state."""

    def variation_name(self) -> str:
        """Short name of the current variation."""
        return "_".join(str(v) for v in self.params.values())

    # -- shared machinery --------------------------------------------------------------
    def setup(self, scene: Scene, rng: np.random.Generator, variation: int) -> None:
        """Bind to ``scene``, select the variation and build the scene."""
        variations = self.variations()
        if not 0 <= variation < len(variations):
            raise ValueError(f"task {self.name!r}: variation {variation} outside [0, {len(variations)})")
        self.scene = scene
        self.variation = int(variation)
        self.params = dict(variations[variation])
        self.objects, self.articulations = [], []
        self.build(scene, rng)
        # Let everything settle under gravity before the first frame.
        scene.step(60)

    def add_object(self, name: str, type_: str, body: int, link: int = -1, color: str = "",
                   size=(0.0, 0.0, 0.0), role: str = "distractor") -> SceneObject:
        """Track a body (or link) in the privileged record."""
        obj = SceneObject(ObjectInfo(name, type_, color, tuple(float(s) for s in size), role), body, link)
        self.objects.append(obj)
        return obj

    def add_articulation(self, name: str, kind: str, body: int, joint: int, closed: float,
                         open_: float, sign: float = 1.0) -> Articulation:
        """Track a joint in the privileged record (state = sign * joint position)."""
        art = Articulation(ArticulationInfo(name, kind, closed, open_), body, joint, sign)
        self.articulations.append(art)
        return art

    def obj(self, name: str) -> SceneObject:
        """The tracked object called ``name``."""
        for o in self.objects:
            if o.info.name == name:
                return o
        raise KeyError(f"task {self.name!r} has no object {name!r}")

    def pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World position and quaternion of a tracked object."""
        o = self.obj(name)
        return self.scene.link_pose(o.body, o.link)

    def art_state(self, name: str) -> float:
        """Current state of a tracked articulation."""
        for a in self.articulations:
            if a.info.name == name:
                return a.sign * float(self.scene.p.getJointState(a.body, a.joint)[0])
        raise KeyError(f"task {self.name!r} has no articulation {name!r}")

    def graspable(self) -> list[tuple[int, int]]:
        """(body, link) pairs the gripper may attach: every movable tracked object except
        furniture (role ``fixture``), though handles are always graspable."""
        out = []
        for o in self.objects:
            if o.info.role == "fixture" and o.info.type != "handle":
                continue
            if o.link < 0 and self.scene.p.getDynamicsInfo(o.body, -1)[0] <= 0:
                continue  # static bodies (plate, lamp, pegs) cannot be picked up
            out.append((o.body, o.link))
        return out

    def state(self) -> dict[str, np.ndarray]:
        """Object-centric state: positions (K,3), quaternions (K,4), articulations (M,), held."""
        pos, orn = [], []
        for o in self.objects:
            p_, q_ = self.scene.link_pose(o.body, o.link)
            pos.append(p_)
            orn.append(q_)
        k = len(self.objects)
        held = -1
        if self.scene.held is not None:
            for i, o in enumerate(self.objects):
                if (o.body, o.link) == self.scene.held:
                    held = i
        return {
            "object_positions": np.array(pos, dtype=np.float32).reshape(k, 3),
            "object_quaternions": np.array(orn, dtype=np.float32).reshape(k, 4),
            "articulation_states": np.array([self.art_state(a.info.name) for a in self.articulations],
                                            dtype=np.float32),
            "held_object": np.int32(held),
        }

    # -- waypoint helpers --------------------------------------------------------------
    @staticmethod
    def pick(label: str, position, yaw: float, grasp_z: float, above: float = 0.12,
             lift_z: float = 0.25) -> list[Waypoint]:
        """Reach above, descend and grasp, lift: three segments."""
        q = top_down_quat(yaw)
        x, y = float(position[0]), float(position[1])
        return [
            Waypoint(np.array([x, y, grasp_z + above]), q, True, f"reach for the {label}"),
            Waypoint(np.array([x, y, grasp_z]), q, False, f"grasp the {label}"),
            Waypoint(np.array([x, y, lift_z]), q, False, f"lift the {label}"),
        ]

    @staticmethod
    def place(label: str, dest: str, position, yaw: float, release_z: float, above: float = 0.1,
              preposition: str = "onto", retreat: float = 0.1) -> list[Waypoint]:
        """Carry above the destination, lower and release, move straight up: three segments."""
        q = top_down_quat(yaw)
        x, y = float(position[0]), float(position[1])
        return [
            Waypoint(np.array([x, y, release_z + above]), q, False, f"move the {label} above the {dest}"),
            Waypoint(np.array([x, y, release_z]), q, True, f"place the {label} {preposition} the {dest}"),
            Waypoint(np.array([x, y, release_z + retreat]), q, True, "move the gripper up"),
        ]

    def carry(self, obj_name: str, label: str, dest: str, object_target, yaw: float | None = None,
              above: float = 0.1, preposition: str = "onto") -> list[Waypoint]:
        """``place`` for the held ``obj_name`` so that the object (not the hand) ends at
        ``object_target``; the hand keeps its grasp offset. ``yaw`` None keeps the hand's yaw."""
        obj_pos, _ = self.pose(obj_name)
        ee = self.scene.ee_pose()
        if yaw is None:
            yaw = finger_yaw(ee[3:])
        target = np.asarray(object_target, dtype=np.float64) + (ee[:3] - obj_pos)
        return self.place(label, dest, target, yaw, float(target[2]), above, preposition)

    @staticmethod
    def retreat(position, yaw: float, z: float, label: str = "move the gripper away") -> Waypoint:
        """Move straight up (or to ``z``) with the gripper open."""
        return Waypoint(np.array([float(position[0]), float(position[1]), z]), top_down_quat(yaw), True, label)
