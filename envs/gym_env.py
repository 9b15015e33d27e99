"""Gymnasium environment: one keyframe action (end-effector pose + gripper) per step.

Observation (a dict): ``front_rgb`` and ``wrist_rgb`` (H, W, 3) uint8, ``joint_positions`` (7),
``joint_velocities`` (7), ``gripper_open`` (1), ``ee_pose`` (7: xyz + quaternion xyzw) and the
object-centric state ``object_positions`` (K, 3), ``object_quaternions`` (K, 4),
``object_mask`` (K,) (1 for real objects; K is the task's largest object count, smaller
variations are zero-padded), ``articulation_states`` (M,), ``held_object`` (1,) (-1 = none).
Object names/types/colours are in ``env.scene_description()``; the goal text in ``info["goal"]``.

Action: 8 floats, target grasp-point position (3), quaternion xyzw (4), gripper open (> 0.5).
A motion that cannot be executed (unreachable pose, collision, timeout) ends the step with
``info["motion_failed"] = True`` and ``info["failure"]`` naming the reason; it never raises.
``reset(seed=s, options={"variation": v})`` rebuilds exactly the scene the expert saw for
(task, s, v); without ``variation`` it is ``s mod number_of_variations`` as in demo generation.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.control import Controller
from envs.expert import build_task, default_variation
from envs.scene import CameraSpec, Scene
from envs.tasks import get_task
from rdd.checks import FLAG, CheckedOptions, number, whole


class RLBenchStyleEnv(CheckedOptions, gym.Env):
    """A task of the suite behind the gymnasium API.

    Its options' ranges are ``OPTION_RULES`` (the constructor and ``check_options`` apply them;
    demo generation, which takes the same physics options, too).
    """

    metadata = {"render_modes": ["rgb_array"]}
    OPTION_RULES = {"image_size": whole(8, 4096), "max_steps": whole(1), "render_images": FLAG,
                    "ticks_per_frame": whole(1), "motion_timeout": number(0.0, exclusive_min=True)}

    @classmethod
    def option_owner(cls) -> str:
        """``env`` (the config group and the harness's name for it)."""
        return "env"

    def __init__(self, task: str, image_size: int = 128, max_steps: int = 30, render_images: bool = True,
                 ticks_per_frame: int = 12, motion_timeout: float = 3.0):
        opts = self.check_options(image_size=image_size, max_steps=max_steps, render_images=render_images,
                                  ticks_per_frame=ticks_per_frame, motion_timeout=motion_timeout)
        self.task_name = task
        self.camera = CameraSpec(width=opts["image_size"], height=opts["image_size"])
        self.render_images = render_images
        self.max_steps = opts["max_steps"]
        self.ticks_per_frame = opts["ticks_per_frame"]
        self.motion_timeout = opts["motion_timeout"]
        self.render_mode = "rgb_array"
        self._scene: Scene | None = None
        self.task = None
        self.seed_value: int | None = None
        self.steps = 0
        self.num_objects, self.num_articulations = self._probe_sizes()
        h = w = int(image_size)
        box = lambda *shape, lo=-np.inf, hi=np.inf: spaces.Box(lo, hi, shape=shape, dtype=np.float32)  # noqa: E731
        self.observation_space = spaces.Dict({
            "front_rgb": spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8),
            "wrist_rgb": spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8),
            "joint_positions": box(7),
            "joint_velocities": box(7),
            "gripper_open": box(1, lo=0.0, hi=1.0),
            "ee_pose": box(7),
            "object_positions": box(self.num_objects, 3),
            "object_quaternions": box(self.num_objects, 4),
            "object_mask": box(self.num_objects, lo=0.0, hi=1.0),
            "articulation_states": box(self.num_articulations),
            "held_object": spaces.Box(-1, max(self.num_objects - 1, 0), shape=(1,), dtype=np.int32),
        })
        lo = np.array([-1.0, -1.0, -0.1, -1, -1, -1, -1, 0], dtype=np.float32)
        hi = np.array([1.5, 1.0, 1.2, 1, 1, 1, 1, 1], dtype=np.float32)
        self.action_space = spaces.Box(lo, hi, dtype=np.float32)

    def _probe_sizes(self) -> tuple[int, int]:
        """Largest object and articulation counts over the task's variations."""
        task = get_task(self.task_name)
        scene = Scene(camera=self.camera, render=False)
        try:
            k = m = 0
            for v in range(len(task.variations())):
                scene.reset_world()
                _, t = build_task(self.task_name, 0, v, scene=scene)
                k, m = max(k, len(t.objects)), max(m, len(t.articulations))
            return k, m
        finally:
            scene.close()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Rebuild the scene for ``seed`` (and ``options["variation"]``); returns (obs, info)."""
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        variation = (options or {}).get("variation")
        if self._scene is None:
            self._scene = Scene(camera=self.camera, render=self.render_images)
        _, self.task = build_task(self.task_name, int(seed), variation, scene=self._scene)
        self.seed_value = int(seed)
        self.steps = 0
        self.controller = Controller(self._scene, ticks_per_frame=self.ticks_per_frame)
        return self._observation(), self._info(None, 0)

    def step(self, action):
        """Execute one keyframe action; returns (obs, reward, terminated, truncated, info)."""
        if self.task is None:
            raise RuntimeError("call reset() before step()")
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (8,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be 8 finite floats (xyz, quaternion xyzw, gripper), got {action!r}")
        quat = a[3:7]
        norm = np.linalg.norm(quat)
        failure = None
        frames = 0
        if norm < 1e-6:
            failure = "unreachable"
        else:
            res = self.controller.move(a[:3], quat / norm, bool(a[7] > 0.5), self.task.graspable(),
                                       timeout=self.motion_timeout)
            failure, frames = res.failure, res.frames
        self.steps += 1
        success = self.task.success()
        terminated = bool(success)
        truncated = bool(not terminated and self.steps >= self.max_steps)
        return self._observation(), float(success), terminated, truncated, self._info(failure, frames)

    def render(self):
        """Front camera image."""
        return self._scene.render()["front"]

    def close(self) -> None:
        """Release the physics clients."""
        if self._scene is not None:
            self._scene.close()
            self._scene = None

    # ---------------------------------------------------------------- helpers
    def scene_description(self) -> dict[str, Any]:
        """Static description of the current scene (objects, articulations, variation)."""
        return {
            "task": self.task_name, "seed": self.seed_value, "variation": self.task.variation,
            "variation_params": dict(self.task.params), "goal": self.task.goal(),
            "objects": [o.info.to_json() for o in self.task.objects],
            "articulations": [a.info.to_json() for a in self.task.articulations],
        }

    def _info(self, failure: str | None, frames: int) -> dict[str, Any]:
        return {
            "goal": self.task.goal(), "success": bool(self.task.success()), "variation": self.task.variation,
            "motion_failed": failure is not None, "failure": failure, "frames": frames,
        }

    def _observation(self) -> dict[str, np.ndarray]:
        s = self._scene
        if self.render_images:
            imgs = s.render()
        else:
            blank = np.zeros((self.camera.height, self.camera.width, 3), np.uint8)
            imgs = {"front": blank, "wrist": blank}
        q, qd = s.arm_state()
        st = self.task.state()
        k = len(self.task.objects)
        pos = np.zeros((self.num_objects, 3), np.float32)
        orn = np.zeros((self.num_objects, 4), np.float32)
        mask = np.zeros(self.num_objects, np.float32)
        pos[:k], orn[:k], mask[:k] = st["object_positions"], st["object_quaternions"], 1.0
        arts = np.zeros(self.num_articulations, np.float32)
        arts[: len(st["articulation_states"])] = st["articulation_states"]
        return {
            "front_rgb": imgs["front"], "wrist_rgb": imgs["wrist"],
            "joint_positions": q.astype(np.float32), "joint_velocities": qd.astype(np.float32),
            "gripper_open": np.array([1.0 if s.gripper_open else 0.0], np.float32),
            "ee_pose": s.ee_pose().astype(np.float32),
            "object_positions": pos, "object_quaternions": orn, "object_mask": mask,
            "articulation_states": arts, "held_object": np.array([st["held_object"]], np.int32),
        }


def make_env(task: str, **kwargs) -> RLBenchStyleEnv:
    """Construct the environment for ``task`` (keyword arguments as ``RLBenchStyleEnv``)."""
    return RLBenchStyleEnv(task, **kwargs)


__all__ = ["RLBenchStyleEnv", "default_variation", "make_env"]
