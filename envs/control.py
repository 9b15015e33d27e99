"""Keyframe controller: an end-effector target pose + gripper state -> IK path -> physics.

Like RLBench's end-effector-pose-via-planning action mode, but with a straight Cartesian path
(position lerp, orientation slerp) solved by IK at every centimetre, retimed so the fastest joint
moves at a constant speed. The arm therefore moves at clearly non-zero joint velocity between
targets and comes to rest at each target, which is what the expert keyframe rule looks for.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from envs.panda import HOME_Q, SIDE_SEEDS
from envs.scene import PHYSICS_HZ, Scene

STOP_VELOCITY = 0.1  # rad/s: the keyframe rule's stopping_delta
FAILURES = ("unreachable", "collision", "timeout")


@dataclass
class MotionResult:
    """Outcome of one keyframe action; ``failure`` is None on success."""

    failure: str | None = None
    frames: int = 0
    ik_error: float = 0.0

    @property
    def ok(self) -> bool:
        """True when the arm reached the target."""
        return self.failure is None


def _slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    q0 = q0 / np.linalg.norm(q0)
    q1 = q1 / np.linalg.norm(q1)
    dot = float(q0 @ q1)
    if dot < 0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1 - t) * theta) * q0 + np.sin(t * theta) * q1) / np.sin(theta)


class Controller:
    """Executes keyframe actions on a ``Scene``, calling ``on_frame`` at the recording rate."""

    def __init__(
        self,
        scene: Scene,
        ticks_per_frame: int = 12,
        joint_speed: float = 0.8,
        min_duration: float = 0.45,
        ramp: float = 0.1,
        max_ik_error: float = 0.01,
        arrive_tolerance: float = 0.015,
        on_frame: Callable[[], None] | None = None,
    ):
        self.scene = scene
        self.ticks_per_frame = int(ticks_per_frame)
        self.joint_speed = float(joint_speed)
        self.min_duration = float(min_duration)
        self.ramp = float(ramp)
        self.max_ik_error = float(max_ik_error)
        self.arrive_tolerance = float(arrive_tolerance)
        self.on_frame = on_frame

    def plan(self, position, quaternion) -> tuple[np.ndarray | None, float]:
        """Joint waypoints along the straight path to the pose, or None when unreachable."""
        scene = self.scene
        # Plan from where the arm is (not where it was told to go), so a motion that ended
        # short of its target does not make the next one start with a dead band.
        start_q = scene.arm_state()[0]
        for j, q in enumerate(start_q):
            scene.ik.resetJointState(scene.ik_robot, j, q)
        s = scene.ik.getLinkState(scene.ik_robot, 11, computeForwardKinematics=True)
        p0, q0 = np.array(s[4]), np.array(s[5])
        p1 = np.asarray(position, dtype=np.float64)
        q1 = np.asarray(quaternion, dtype=np.float64)
        q1 = q1 / np.linalg.norm(q1)
        angle = 2 * np.arccos(min(1.0, abs(float(q0 @ q1))))
        n = int(max(2, np.ceil(np.linalg.norm(p1 - p0) / 0.02), np.ceil(angle / 0.1)))
        qs = [start_q]
        err = 0.0
        for i in range(1, n + 1):
            t = i / n
            q, err = scene.solve_ik(p0 + t * (p1 - p0), _slerp(q0, q1, t), qs[-1])
            # An IK branch switch shows up as a jump between neighbouring path points.
            if np.max(np.abs(q - qs[-1])) > 0.6 or (i == n and err > self.max_ik_error):
                break
            qs.append(q)
        else:
            return np.stack(qs), err
        # No straight Cartesian path: fall back to a joint-space move to an IK solution,
        # as a motion planner would (seeds: the current arm, then canonical postures).
        best, best_err = None, np.inf
        for seed in (start_q, np.array(HOME_Q), *map(np.array, SIDE_SEEDS)):
            q, e = scene.solve_ik(p1, q1, seed, iterations=10)
            if e < best_err:
                best, best_err = q, e
            if e <= self.max_ik_error:
                break
        if best is None or best_err > self.max_ik_error:
            return None, best_err
        steps = int(max(2, np.ceil(np.max(np.abs(best - start_q)) / 0.05)))
        return np.stack([start_q + (best - start_q) * k / steps for k in range(steps + 1)]), best_err

    def _profile(self, path: np.ndarray):
        """Per-tick joint targets and velocities for a trapezoidal max-joint-speed profile."""
        seg = np.max(np.abs(np.diff(path, axis=0)), axis=1)
        s_cum = np.concatenate([[0.0], np.cumsum(seg)])
        total = float(s_cum[-1])
        ramp = self.ramp
        duration = max(total / self.joint_speed + ramp, self.min_duration)
        v = total / max(duration - ramp, 1e-9)
        acc = v / ramp
        ticks = int(np.ceil(duration * PHYSICS_HZ))
        targets, vels = [], []
        for k in range(1, ticks + 1):
            t = k / PHYSICS_HZ
            if t < ramp:
                s, sd = 0.5 * acc * t * t, acc * t
            elif t < duration - ramp:
                s, sd = 0.5 * acc * ramp * ramp + v * (t - ramp), v
            else:
                tr = max(duration - t, 0.0)
                s, sd = total - 0.5 * acc * tr * tr, acc * tr
            s = min(max(s, 0.0), total)
            if total <= 1e-12:
                targets.append(path[-1])
                vels.append(np.zeros(7))
                continue
            i = int(np.clip(np.searchsorted(s_cum, s, side="right") - 1, 0, len(seg) - 1))
            frac = 0.0 if seg[i] <= 1e-12 else (s - s_cum[i]) / seg[i]
            q = path[i] + np.clip(frac, 0, 1) * (path[i + 1] - path[i])
            dq_ds = (path[i + 1] - path[i]) / max(seg[i], 1e-12)
            targets.append(q)
            vels.append(dq_ds * sd)
        return targets, vels, duration

    def move(self, position, quaternion, gripper_open: bool, graspable=(), timeout: float = 3.0) -> MotionResult:
        """Move the grasp point to the pose, then set the gripper (at the arrival frame).

        Never raises for a failed motion: returns a result whose ``failure`` names the reason.
        """
        scene = self.scene
        path, err = self.plan(position, quaternion)
        if path is None:
            return MotionResult("unreachable", 0, float(err))
        targets, vels, duration = self._profile(path)
        goal = np.asarray(position, dtype=np.float64)
        frames = 0
        tick = 0
        limit = len(targets) + int(timeout * PHYSICS_HZ)
        while tick < limit:
            if tick < len(targets):
                scene.arm_target = targets[tick]
                scene._apply_arm_command(targets[tick], vels[tick])
            else:
                scene._apply_arm_command(scene.arm_target, np.zeros(7))
            scene.step(1)
            tick += 1
            if tick % 4 == 0 and scene.arm_collision():
                scene.arm_target = scene.arm_state()[0]
                scene._apply_arm_command(scene.arm_target, np.zeros(7))
                return MotionResult("collision", frames, float(err))
            if tick % self.ticks_per_frame:
                continue
            _, qd = scene.arm_state()
            # Arrived: at rest by the keyframe rule's measure, and at the target (a motion
            # blocked by contact comes to rest elsewhere and runs into the timeout).
            arrived = (tick >= 0.5 * len(targets) and np.all(np.abs(qd) <= STOP_VELOCITY)
                       and np.linalg.norm(scene.ee_pose()[:3] - goal) < self.arrive_tolerance)
            if arrived:
                # Hold the rest of the (sub-millimetre) deceleration tail as the target.
                scene.arm_target = path[-1]
                scene._apply_arm_command(path[-1], np.zeros(7))
                scene.set_gripper(gripper_open, graspable)
            if self.on_frame is not None:
                self.on_frame()
            frames += 1
            if arrived:
                return MotionResult(None, frames, float(err))
        return MotionResult("timeout", frames, float(err))
