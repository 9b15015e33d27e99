"""Scripted expert demonstrations: run a task's waypoints through the controller and record.

Frames are recorded at ``1 / (ticks_per_frame / 240 Hz)`` (20 Hz by default). Each waypoint
ends at its arrival frame, the first frame at which every arm joint moves at <= 0.1 rad/s (the
keyframe rule's ``stopping_delta``), and a gripper change is applied exactly at that frame. So
the expert keyframe rule recovers the waypoint boundaries, which become ``episode.segments``.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from envs.control import Controller
from envs.record import PrivilegedRecorder
from envs.scene import CameraSpec, Scene
from envs.tasks import get_task
from envs.tasks.base import Task
from rdd.data.episode import Episode
from rdd.segments import keyframes_to_segments

VIEWS = ("front", "wrist")


def task_rng(task_name: str, seed: int) -> np.random.Generator:
    """The random stream that places a task's objects for ``seed`` (independent across tasks)."""
    return np.random.default_rng([int(seed), zlib.crc32(task_name.encode())])


def default_variation(task: Task, seed: int) -> int:
    """Variation used when none is given: ``seed mod number of variations`` (balanced splits)."""
    return int(seed) % len(task.variations())


def build_task(task_name: str, seed: int, variation: int | None = None, scene: Scene | None = None,
               render: bool = True, camera: CameraSpec | None = None) -> tuple[Scene, Task]:
    """A scene reset to the exact layout of (task, seed, variation)."""
    task = get_task(task_name)
    if scene is None:
        scene = Scene(camera=camera, render=render)
    else:
        scene.reset_world()
    var = default_variation(task, seed) if variation is None else int(variation)
    task.setup(scene, task_rng(task_name, seed), var)
    return scene, task


@dataclass
class FrameRecorder:
    """Collects per-frame observations from a scene and task."""

    scene: Scene
    task: Task
    render: bool = True
    images: dict[str, list[np.ndarray]] = field(default_factory=lambda: {v: [] for v in VIEWS})
    joint_positions: list[np.ndarray] = field(default_factory=list)
    joint_velocities: list[np.ndarray] = field(default_factory=list)
    gripper_open: list[float] = field(default_factory=list)
    ee_poses: list[np.ndarray] = field(default_factory=list)
    privileged: PrivilegedRecorder | None = None

    def __post_init__(self) -> None:
        self.privileged = PrivilegedRecorder([o.info for o in self.task.objects],
                                             [a.info for a in self.task.articulations])

    def __call__(self) -> None:
        """Record the current state as one frame."""
        s = self.scene
        if self.render:
            for view, img in s.render().items():
                self.images[view].append(img)
        q, qd = s.arm_state()
        self.joint_positions.append(q)
        self.joint_velocities.append(qd)
        self.gripper_open.append(1.0 if s.gripper_open else 0.0)
        self.ee_poses.append(s.ee_pose())
        st = self.task.state()
        self.privileged.append(st["object_positions"], st["object_quaternions"],
                               st["articulation_states"], int(st["held_object"]), self.task.success())

    def __len__(self) -> int:
        return len(self.gripper_open)


@dataclass
class ExpertResult:
    """A recorded demonstration and whether the expert succeeded."""

    episode: Episode
    privileged: dict[str, np.ndarray]
    success: bool
    failure: str | None


def run_expert(task_name: str, seed: int, variation: int | None = None, render: bool = True,
               camera: CameraSpec | None = None, split: str | None = None,
               ticks_per_frame: int = 12, motion_timeout: float = 3.0) -> ExpertResult:
    """Record one scripted demonstration of ``task_name`` for ``seed`` (``ticks_per_frame`` and
    ``motion_timeout`` as the gym env's, so demos and evaluation run the same physics)."""
    scene, task = build_task(task_name, seed, variation, render=render, camera=camera)
    try:
        rec = FrameRecorder(scene, task, render=render)
        ctrl = Controller(scene, ticks_per_frame=ticks_per_frame, on_frame=rec)
        rec()  # frame 0: the initial state
        keyframes: list[int] = []
        instructions: list[str] = []
        waypoints: list[dict[str, Any]] = []
        failure = None
        for wp in task.expert():
            res = ctrl.move(wp.position, wp.quaternion, wp.gripper_open, task.graspable(),
                            timeout=motion_timeout)
            if not res.ok:
                failure = f"{res.failure} at waypoint {len(keyframes)} ({wp.instruction})"
                break
            keyframes.append(len(rec) - 1)
            instructions.append(wp.instruction)
            waypoints.append({
                "position": [float(v) for v in wp.position],
                "quaternion": [float(v) for v in wp.quaternion],
                "gripper_open": bool(wp.gripper_open),
                "instruction": wp.instruction,
            })
        success = failure is None and task.success()
        n = len(rec)
        if failure is not None and (not keyframes or keyframes[-1] != n - 1):
            keyframes.append(n - 1)
            instructions.append("(failed motion)")
        segments = keyframes_to_segments(keyframes, n)
        meta: dict[str, Any] = {
            "task": task.name, "seed": int(seed), "split": split, "pretraining": task.pretraining,
            "variation": task.variation, "variation_name": task.variation_name(),
            "variation_params": task.params, "waypoints": waypoints, "success": bool(success),
            "failure": failure, "frame_rate": 240.0 / ticks_per_frame,
            "image_size": [scene.camera.height, scene.camera.width] if render else None,
        }
        meta.update(rec.privileged.meta())
        views = {v: np.stack(rec.images[v]) for v in VIEWS} if render else {}
        episode = Episode(
            name=f"{task.name}_seed{seed}",
            views=views,
            gripper_open=np.array(rec.gripper_open),
            joint_positions=np.stack(rec.joint_positions),
            joint_velocities=np.stack(rec.joint_velocities),
            ee_poses=np.stack(rec.ee_poses),
            goal=task.goal(),
            task=task.name,
            segments=segments,
            instructions=instructions,
            meta=meta,
        )
        return ExpertResult(episode, rec.privileged.arrays(), bool(success), failure)
    finally:
        scene.close()
