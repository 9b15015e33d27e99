"""The shared pybullet scene: table, Franka Panda, cameras, inverse kinematics and grasping.

One ``Scene`` owns one DIRECT-mode physics client, so several scenes (or worker processes) never
share state and a scene rebuilt from the same seed replays identically. Its body builders are
:class:`envs.primitives.PrimitiveBuilders`; the robot's constants are :mod:`envs.panda`'s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from envs.bullet import bullet_client, pb, pybullet_data
from envs.panda import (
    ARM_FORCES,
    ARM_JOINTS,
    EE_LINK,
    FINGER_JOINTS,
    FINGER_OPEN,
    HAND_LINK,
    HOME_Q,
    JOINT_LOWER,
    JOINT_UPPER,
    SIDE_SEEDS,
    lite_panda_urdf,
)
from envs.poses import gripper_quat
from envs.primitives import PrimitiveBuilders
from envs.quiet import native_output_silenced

PHYSICS_HZ = 240
TABLE_TOP = 0.0
# The fixed front camera looks down at the workspace from the far side of the table.
FRONT_EYE = (0.95, 0.0, 0.75)
FRONT_TARGET = (0.45, 0.0, 0.05)
ROBOT_BASE = (-0.05, 0.0, TABLE_TOP)


@dataclass
class CameraSpec:
    """Image size and intrinsics shared by both views."""

    width: int = 128
    height: int = 128
    fov: float = 50.0
    near: float = 0.01
    far: float = 4.0


class Scene(PrimitiveBuilders):
    """A DIRECT pybullet world with a table and a Panda; tasks add their objects to it."""

    def __init__(self, camera: CameraSpec | None = None, render: bool = True):
        self.camera = camera or CameraSpec()
        self.render_enabled = render
        with native_output_silenced():  # each client prints "argv[0]="
            self.p = bullet_client.BulletClient(connection_mode=pb.DIRECT)
            self.ik = bullet_client.BulletClient(connection_mode=pb.DIRECT)
        self.p.setAdditionalSearchPath(pybullet_data.getDataPath())
        # A second client holding only the arm: inverse kinematics is seeded and checked there
        # without disturbing the simulated robot.
        self.ik_robot = self.ik.loadURDF(lite_panda_urdf(), basePosition=ROBOT_BASE, useFixedBase=True)
        self._proj = self.p.computeProjectionMatrixFOV(
            self.camera.fov, self.camera.width / self.camera.height, self.camera.near, self.camera.far
        )
        self.reset_world()

    # ------------------------------------------------------------------ world
    def reset_world(self) -> None:
        """Empty the world and rebuild the table and robot at the home pose.

        (No floor: every large polygon costs TinyRenderer time, and the cameras look at the table.)
        """
        p = self.p
        p.resetSimulation()
        p.setGravity(0, 0, -9.81)
        p.setTimeStep(1.0 / PHYSICS_HZ)
        p.setPhysicsEngineParameter(numSolverIterations=50, deterministicOverlappingPairs=1)
        self.table = self.add_box((0.55, 0.65, 0.02), (0.45, 0, TABLE_TOP - 0.02), color="wood", mass=0)
        for sx in (-1, 1):
            for sy in (-1, 1):
                self.add_box((0.03, 0.03, 0.37), (0.45 + sx * 0.5, sy * 0.6, -0.41), color="brown", mass=0)
        self.robot = p.loadURDF(lite_panda_urdf(), basePosition=ROBOT_BASE, useFixedBase=True)
        for link in range(-1, 12):
            shade = (0.92, 0.92, 0.92, 1) if link not in (8, 9, 10) else (0.25, 0.25, 0.25, 1)
            if link in (1, 3, 5):
                shade = (0.85, 0.85, 0.88, 1)
            p.changeVisualShape(self.robot, link, rgbaColor=shade)
        for j, q in zip(ARM_JOINTS, HOME_Q, strict=True):
            p.resetJointState(self.robot, j, q)
        for j in FINGER_JOINTS:
            p.resetJointState(self.robot, j, FINGER_OPEN)
            p.changeDynamics(self.robot, j, lateralFriction=1.5)
        self.arm_target = np.array(HOME_Q, dtype=np.float64)
        self.gripper_open = True
        self.grasp_constraint: int | None = None
        self.held: tuple[int, int] | None = None  # (body, link) attached to the hand
        self.fixtures: set[int] = {self.table}
        self.step_hooks: list = []
        self._apply_arm_command(self.arm_target, np.zeros(7))
        self._apply_gripper_command()

    def close(self) -> None:
        """Disconnect both physics clients."""
        for client in (self.p, self.ik):
            try:
                client.disconnect()
            except pb.error:
                pass

    # ----------------------------------------------------------------- robot
    def arm_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Arm joint positions and velocities (7 each)."""
        states = self.p.getJointStates(self.robot, ARM_JOINTS)
        return (np.array([s[0] for s in states]), np.array([s[1] for s in states]))

    def ee_pose(self) -> np.ndarray:
        """Grasp-point pose: xyz + quaternion xyzw."""
        s = self.p.getLinkState(self.robot, EE_LINK, computeForwardKinematics=True)
        return np.concatenate([s[4], s[5]])

    def finger_width(self) -> float:
        """Current opening between the fingers in metres."""
        return float(sum(self.p.getJointState(self.robot, j)[0] for j in FINGER_JOINTS))

    def link_pose(self, body: int, link: int) -> tuple[np.ndarray, np.ndarray]:
        """World position and quaternion of a body's base (link -1) or link."""
        if link < 0:
            pos, orn = self.p.getBasePositionAndOrientation(body)
        else:
            s = self.p.getLinkState(body, link, computeForwardKinematics=True)
            pos, orn = s[4], s[5]
        return np.array(pos), np.array(orn)

    def _apply_arm_command(self, q: np.ndarray, qd: np.ndarray) -> None:
        self.p.setJointMotorControlArray(
            self.robot, ARM_JOINTS, pb.POSITION_CONTROL,
            targetPositions=list(q), targetVelocities=list(qd), forces=list(ARM_FORCES),
            positionGains=[0.3] * 7, velocityGains=[1.0] * 7,
        )

    def _apply_gripper_command(self) -> None:
        target = FINGER_OPEN if self.gripper_open else 0.0
        force = 40.0 if self.held is None else 10.0
        self.p.setJointMotorControlArray(
            self.robot, FINGER_JOINTS, pb.POSITION_CONTROL,
            targetPositions=[target, target], forces=[force, force],
        )

    def step(self, n: int = 1) -> None:
        """Advance physics ``n`` ticks, running the tasks' per-tick hooks."""
        for _ in range(n):
            self.p.stepSimulation()
            for hook in self.step_hooks:
                hook()

    def solve_ik(self, position, quaternion, seed_q, iterations: int = 6) -> tuple[np.ndarray, float]:
        """Joint angles reaching the pose from ``seed_q`` and the remaining position error (m)."""
        ik = self.ik
        for j, q in zip(ARM_JOINTS, seed_q, strict=True):
            ik.resetJointState(self.ik_robot, j, q)
        rest = list(seed_q) + [FINGER_OPEN, FINGER_OPEN]  # null space pulls toward the seed
        lower = list(JOINT_LOWER) + [0.0, 0.0]
        upper = list(JOINT_UPPER) + [FINGER_OPEN, FINGER_OPEN]
        ranges = [u - lo for u, lo in zip(upper, lower, strict=True)]
        q = np.asarray(seed_q, dtype=np.float64)
        err = np.inf
        for _ in range(iterations):
            sol = ik.calculateInverseKinematics(
                self.ik_robot, EE_LINK, list(position), list(quaternion),
                lowerLimits=lower, upperLimits=upper, jointRanges=ranges, restPoses=rest,
                maxNumIterations=50, residualThreshold=1e-4,
            )
            q = np.clip(np.array(sol[:7]), JOINT_LOWER, JOINT_UPPER)
            for j, v in zip(ARM_JOINTS, q, strict=True):
                ik.resetJointState(self.ik_robot, j, v)
            s = ik.getLinkState(self.ik_robot, EE_LINK, computeForwardKinematics=True)
            pos_err = float(np.linalg.norm(np.array(s[4]) - np.asarray(position)))
            dot = abs(float(np.dot(np.array(s[5]), np.asarray(quaternion))))
            rot_err = 2 * np.arccos(min(1.0, dot))
            err = pos_err + 0.05 * rot_err  # 0.05 m per radian
            if pos_err < 1e-3 and rot_err < 0.02:
                break
        return q, err

    def best_side_quat(self, position, approach=(1.0, 0.0, 0.0)) -> np.ndarray:
        """Horizontal-approach orientation (fingers opening horizontally) the arm reaches best.

        The hand is symmetric under a half turn about its approach axis, so both finger
        directions grasp the same way; joint 7's range makes only one reachable in places.
        """
        best, best_err = None, np.inf
        a = np.asarray(approach, dtype=np.float64)
        side = np.cross([0.0, 0.0, 1.0], a)
        for sign in (1.0, -1.0):
            quat = gripper_quat(a, sign * side)
            for seed in SIDE_SEEDS:
                _, err = self.solve_ik(position, quat, seed, iterations=10)
                if err < best_err:
                    best, best_err = quat, err
        return best

    # ---------------------------------------------------------------- grasping
    def set_gripper(self, open_: bool, graspable) -> None:
        """Open or close the gripper; closing on a graspable object attaches it (as RLBench does).

        ``graspable`` lists ``(body, link)`` pairs that may be attached.
        """
        if open_ == self.gripper_open:
            return
        self.gripper_open = open_
        if open_:
            if self.grasp_constraint is not None:
                self.p.removeConstraint(self.grasp_constraint)
            self.grasp_constraint = None
            self.held = None
        else:
            target = self._object_between_fingers(graspable)
            if target is not None:
                self._attach(*target)
        self._apply_gripper_command()

    def _object_between_fingers(self, graspable):
        """The graspable (body, link) whose surface both fingers nearly touch, nearest first."""
        ee = self.ee_pose()[:3]
        best, best_d = None, np.inf
        for body, link in graspable:
            near = []
            for finger in FINGER_JOINTS:
                pts = self.p.getClosestPoints(self.robot, body, 0.06, linkIndexA=finger, linkIndexB=link)
                near.append(min((pt[8] for pt in pts), default=np.inf))
            if max(near) > FINGER_OPEN + 0.006:  # each finger at most its open stroke away
                continue
            pos, _ = self.link_pose(body, link)
            # The grasp point must lie inside the object's box, inflated by 1.5 cm.
            lo, hi = self.p.getAABB(body, link)
            if np.any(ee < np.array(lo) - 0.015) or np.any(ee > np.array(hi) + 0.015):
                continue
            d = float(np.linalg.norm(pos - ee))
            if d < best_d:
                best, best_d = (body, link), d
        return best

    def _attach(self, body: int, link: int) -> None:
        p = self.p
        hs = p.getLinkState(self.robot, EE_LINK, computeForwardKinematics=True)
        hand_pos, hand_orn = hs[4], hs[5]
        obj_pos, obj_orn = self.link_pose(body, link)
        inv_pos, inv_orn = p.invertTransform(hand_pos, hand_orn)
        rel_pos, rel_orn = p.multiplyTransforms(inv_pos, inv_orn, obj_pos, obj_orn)
        # The child frame is the object's own frame (link frame for links, whose inertial frame
        # pybullet uses for constraints, so correct for the inertial offset).
        if link >= 0:
            info = p.getLinkState(body, link)
            inertial_pos, inertial_orn = info[2], info[3]
        else:
            dyn = p.getDynamicsInfo(body, -1)
            inertial_pos, inertial_orn = dyn[3], dyn[4]
        inv_ipos, inv_iorn = p.invertTransform(inertial_pos, inertial_orn)
        cid = p.createConstraint(
            self.robot, EE_LINK, body, link, pb.JOINT_FIXED, (0, 0, 0),
            parentFramePosition=rel_pos, childFramePosition=inv_ipos,
            parentFrameOrientation=rel_orn, childFrameOrientation=inv_iorn,
        )
        p.changeConstraint(cid, maxForce=2000)
        self.grasp_constraint = cid
        self.held = (body, link)

    # ------------------------------------------------------------------ safety
    def arm_collision(self) -> bool:
        """True when an arm link touches anything but the robot, or the hand touches a fixture."""
        for c in self.p.getContactPoints(bodyA=self.robot):
            link, other = c[3], c[2]
            if other == self.robot or link < 0:
                continue
            if self.held is not None and other == self.held[0]:
                continue
            if link < HAND_LINK and link > 0:
                return True
            if link >= HAND_LINK and other in self.fixtures and c[9] > 50.0:
                return True
        return False

    # ------------------------------------------------------------------ cameras
    def render(self) -> dict[str, np.ndarray]:
        """RGB images (H, W, 3) uint8 from the ``front`` and ``wrist`` cameras."""
        cam = self.camera
        views = {"front": self.p.computeViewMatrix(FRONT_EYE, FRONT_TARGET, (0, 0, 1))}
        hs = self.p.getLinkState(self.robot, HAND_LINK, computeForwardKinematics=True)
        rot = np.array(self.p.getMatrixFromQuaternion(hs[5])).reshape(3, 3)
        eye = np.array(hs[4]) + rot @ np.array([0.07, 0.0, 0.02])
        target = np.array(hs[4]) + rot @ np.array([0.0, 0.0, 0.2])
        views["wrist"] = self.p.computeViewMatrix(eye, target, rot @ np.array([-1.0, 0.0, 0.0]))
        out = {}
        for name, view in views.items():
            img = self.p.getCameraImage(
                cam.width, cam.height, view, self._proj, renderer=pb.ER_TINY_RENDERER,
                shadow=0, lightDirection=(0.6, 0.3, 1.0),
            )
            rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (cam.height, cam.width, 4))
            out[name] = np.ascontiguousarray(rgba[:, :, :3])
        return out
