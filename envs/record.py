"""Layout of the privileged (simulator-only) record each expert episode carries.

Stable contract (extend additively only). An episode saved with
``rdd.data.native.save_episode(episode, dir, privileged=record.arrays())`` holds two parts:

1. Per-frame arrays (``privileged.npz``; after ``load_episode`` they are in
   ``episode.meta["privileged"]``), every one with T rows:

   ==================== ============ =====================================================
   key                  shape, dtype meaning
   ==================== ============ =====================================================
   object_positions     (T,K,3) f32  world xyz of each scene object (order = meta objects)
   object_quaternions   (T,K,4) f32  world orientation, quaternion xyzw
   articulation_states  (T,M) f32    drawer opening (m, 0 = shut), button depression (m,
                                     0 = up), tap angle (rad, 0 = shut); order = meta
                                     articulations; M may be 0. A button's lamp lights
                                     once its state reaches half the travel and stays lit
                                     (the running maximum of the state tells it)
   held_object          (T,) i32     index into the objects held by the gripper, -1 = none
   success              (T,) bool    the task's success detector evaluated at that frame
   ==================== ============ =====================================================

2. Static scene description (JSON, ``episode.meta``):

   - ``task`` (str), ``seed`` (int), ``split`` (str or null), ``pretraining`` (bool)
   - ``variation`` (int index), ``variation_name`` (str, e.g. ``"top"``),
     ``variation_params`` (dict, e.g. ``{"drawer": "top"}``)
   - ``objects``: list of K dicts ``{"name", "type", "color", "size", "role"}``:
     ``name`` unique (``"red_block"``, ``"top_drawer_handle"``), ``type`` a noun
     (``"block"``, ``"handle"``, ``"button"``, ``"lid"``...), ``color`` a colour name or ``""``,
     ``size`` the [x, y, z] extents in metres, ``role`` one of ``"target"`` (the goal mentions it),
     ``"distractor"``, ``"fixture"`` (part of furniture, e.g. a handle).
   - ``articulations``: list of M dicts ``{"name", "kind", "closed", "open"}``: ``kind`` one of
     ``"drawer"``, ``"button"``, ``"tap"``; ``closed``/``open`` the state values at rest and
     fully actuated (for normalising ``articulation_states``).
   - ``waypoints``: one dict per expert segment ``{"position": [3], "quaternion": [4],
     "gripper_open": bool, "instruction": str}``: the target the segment ends at.
   - ``success`` (bool): the detector at the last frame; ``record_schema`` (int): this layout's
     version.

Segments (``episode.segments``, half-open, keyframe = end - 1) and one instruction per segment
(``episode.instructions``) are the expert's waypoint boundaries; see ``envs.expert``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

RECORD_SCHEMA_VERSION = 1
PER_FRAME_KEYS = (
    "object_positions",
    "object_quaternions",
    "articulation_states",
    "held_object",
    "success",
)
OBJECT_ROLES = ("target", "distractor", "fixture")
ARTICULATION_KINDS = ("drawer", "button", "tap")


@dataclass
class ObjectInfo:
    """Static description of one scene object (index k of the per-frame arrays)."""

    name: str
    type: str
    color: str = ""
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    role: str = "distractor"

    def to_json(self) -> dict[str, Any]:
        """JSON form stored in ``episode.meta["objects"]``."""
        if self.role not in OBJECT_ROLES:
            raise ValueError(f"object {self.name!r}: role {self.role!r} not in {OBJECT_ROLES}")
        return {
            "name": self.name,
            "type": self.type,
            "color": self.color,
            "size": [float(s) for s in self.size],
            "role": self.role,
        }


@dataclass
class ArticulationInfo:
    """Static description of one articulated degree of freedom (index m of the states)."""

    name: str
    kind: str
    closed: float = 0.0
    open: float = 1.0

    def to_json(self) -> dict[str, Any]:
        """JSON form stored in ``episode.meta["articulations"]``."""
        if self.kind not in ARTICULATION_KINDS:
            raise ValueError(f"articulation {self.name!r}: kind {self.kind!r} not in {ARTICULATION_KINDS}")
        return {"name": self.name, "kind": self.kind, "closed": float(self.closed), "open": float(self.open)}


@dataclass
class PrivilegedRecorder:
    """Accumulates per-frame privileged state while an episode is recorded."""

    objects: list[ObjectInfo]
    articulations: list[ArticulationInfo]
    positions: list[np.ndarray] = field(default_factory=list)
    quaternions: list[np.ndarray] = field(default_factory=list)
    states: list[np.ndarray] = field(default_factory=list)
    held: list[int] = field(default_factory=list)
    success: list[bool] = field(default_factory=list)

    def append(
        self,
        positions: np.ndarray,
        quaternions: np.ndarray,
        states: np.ndarray,
        held: int,
        success: bool,
    ) -> None:
        """Add one frame's state (shapes (K,3), (K,4), (M,))."""
        k, m = len(self.objects), len(self.articulations)
        positions = np.asarray(positions, dtype=np.float32).reshape(k, 3)
        quaternions = np.asarray(quaternions, dtype=np.float32).reshape(k, 4)
        states = np.asarray(states, dtype=np.float32).reshape(m)
        if not -1 <= int(held) < k:
            raise ValueError(f"held object index {held} outside [-1, {k})")
        self.positions.append(positions)
        self.quaternions.append(quaternions)
        self.states.append(states)
        self.held.append(int(held))
        self.success.append(bool(success))

    def __len__(self) -> int:
        return len(self.held)

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-frame arrays, keyed as in ``PER_FRAME_KEYS``."""
        t, k, m = len(self), len(self.objects), len(self.articulations)
        return {
            "object_positions": np.stack(self.positions) if t else np.zeros((0, k, 3), np.float32),
            "object_quaternions": np.stack(self.quaternions) if t else np.zeros((0, k, 4), np.float32),
            "articulation_states": np.stack(self.states) if t else np.zeros((0, m), np.float32),
            "held_object": np.asarray(self.held, dtype=np.int32),
            "success": np.asarray(self.success, dtype=bool),
        }

    def meta(self) -> dict[str, Any]:
        """The static part (``objects`` and ``articulations``) for ``episode.meta``."""
        return {
            "objects": [o.to_json() for o in self.objects],
            "articulations": [a.to_json() for a in self.articulations],
            "record_schema": RECORD_SCHEMA_VERSION,
        }


def validate_privileged(arrays: dict[str, np.ndarray] | Any, meta: dict[str, Any], num_frames: int) -> None:
    """Check a loaded privileged record against this layout; raise ValueError naming the field."""
    k = len(meta.get("objects", []))
    m = len(meta.get("articulations", []))
    expected = {
        "object_positions": (num_frames, k, 3),
        "object_quaternions": (num_frames, k, 4),
        "articulation_states": (num_frames, m),
        "held_object": (num_frames,),
        "success": (num_frames,),
    }
    for key, shape in expected.items():
        if key not in arrays:
            raise ValueError(f"privileged record lacks {key!r}")
        if tuple(arrays[key].shape) != shape:
            raise ValueError(f"privileged {key!r} has shape {tuple(arrays[key].shape)}, expected {shape}")
