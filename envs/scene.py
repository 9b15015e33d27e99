"""The shared pybullet scene: table, Franka Panda, cameras, primitive builders and grasping.

One ``Scene`` owns one DIRECT-mode physics client, so several scenes (or worker processes) never
share state and a scene rebuilt from the same seed replays identically.
"""

from __future__ import annotations

import hashlib
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from envs.quiet import native_output_silenced
from rdd.atomic import write_text_atomic

try:
    with native_output_silenced():  # pybullet prints its build-time banner on import
        import pybullet as pb
        import pybullet_data
        from pybullet_utils import bullet_client
except ImportError as exc:  # pragma: no cover - depends on the install
    raise ImportError(
        "the envs package needs pybullet: pip install 'rdd-harness[sim]'"
    ) from exc

ARM_JOINTS = tuple(range(7))
FINGER_JOINTS = (9, 10)
HAND_LINK = 8
EE_LINK = 11  # panda_grasptarget: the point between the fingertips
HOME_Q = (0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785)
# Postures with the hand horizontal, pointing away from the robot (IK seeds for side grasps).
SIDE_SEEDS = ((0.0, 0.3, 0.0, -2.0, 0.0, 2.3, -0.785), (0.0, 0.3, 0.0, -2.0, 0.0, 2.3, 2.35))
JOINT_LOWER = np.array([-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671])
JOINT_UPPER = np.array([2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671])
ARM_FORCES = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
PHYSICS_HZ = 240
FINGER_OPEN = 0.04
TABLE_TOP = 0.0
# The fixed front camera looks down at the workspace from the far side of the table.
FRONT_EYE = (0.95, 0.0, 0.75)
FRONT_TARGET = (0.45, 0.0, 0.05)
ROBOT_BASE = (-0.05, 0.0, TABLE_TOP)

COLORS: dict[str, tuple[float, float, float, float]] = {
    "red": (0.85, 0.1, 0.1, 1.0),
    "green": (0.1, 0.7, 0.15, 1.0),
    "blue": (0.1, 0.25, 0.9, 1.0),
    "yellow": (0.95, 0.85, 0.1, 1.0),
    "purple": (0.55, 0.15, 0.7, 1.0),
    "orange": (1.0, 0.5, 0.0, 1.0),
    "cyan": (0.1, 0.8, 0.85, 1.0),
    "white": (0.95, 0.95, 0.95, 1.0),
    "black": (0.1, 0.1, 0.1, 1.0),
    "grey": (0.5, 0.5, 0.5, 1.0),
    "brown": (0.45, 0.25, 0.1, 1.0),
    "wood": (0.6, 0.45, 0.3, 1.0),
    "pink": (0.95, 0.6, 0.65, 1.0),
}


def _lite_panda_urdf() -> str:
    """Path of panda.urdf with its collision meshes also used as visuals.

    The stock visual meshes are ~1 MB each and make TinyRenderer ~15x slower; the collision
    meshes keep the silhouette. Kinematics and dynamics are the stock file's, untouched.
    """
    data = Path(pybullet_data.getDataPath()) / "franka_panda"
    text = (data / "panda.urdf").read_text()
    text = text.replace("package://meshes/visual/", "package://meshes/collision/")
    text = text.replace("package://meshes/", f"{data / 'meshes'}/")
    key = hashlib.sha256(text.encode()).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / f"rdd_envs_panda_{key}.urdf"
    if not out.is_file():
        write_text_atomic(out, text)
    return str(out)


@dataclass
class CameraSpec:
    """Image size and intrinsics shared by both views."""

    width: int = 128
    height: int = 128
    fov: float = 50.0
    near: float = 0.01
    far: float = 4.0


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """xyzw quaternion of a 3x3 rotation matrix."""
    m = np.asarray(m, dtype=np.float64)
    tr = np.trace(m)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def gripper_quat(approach: np.ndarray, fingers: np.ndarray) -> np.ndarray:
    """Hand orientation whose approach (local z) and finger-opening (local y) axes are given."""
    z = np.asarray(approach, dtype=np.float64)
    z = z / np.linalg.norm(z)
    y = np.asarray(fingers, dtype=np.float64)
    y = y - z * (y @ z)
    y = y / np.linalg.norm(y)
    x = np.cross(y, z)
    return quat_from_matrix(np.stack([x, y, z], axis=1))


def top_down_quat(yaw: float = 0.0) -> np.ndarray:
    """Gripper pointing down, fingers opening along (cos yaw, sin yaw, 0)."""
    return gripper_quat(np.array([0.0, 0.0, -1.0]), np.array([np.cos(yaw), np.sin(yaw), 0.0]))


class Scene:
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
        self.ik_robot = self.ik.loadURDF(_lite_panda_urdf(), basePosition=ROBOT_BASE, useFixedBase=True)
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
        self.robot = p.loadURDF(_lite_panda_urdf(), basePosition=ROBOT_BASE, useFixedBase=True)
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

    # ------------------------------------------------------------- primitives
    def _rgba(self, color) -> tuple[float, float, float, float]:
        if isinstance(color, str):
            if color not in COLORS:
                raise ValueError(f"unknown colour {color!r}; known: {sorted(COLORS)}")
            return COLORS[color]
        return tuple(color)

    def recolor(self, body: int, link: int, color) -> None:
        """Repaint every visual shape of one link (``-1`` = the base), e.g. a lamp lighting up."""
        self.p.changeVisualShape(body, link, rgbaColor=self._rgba(color))

    def add_box(self, half_extents, position, quaternion=(0, 0, 0, 1), color="grey", mass=0.1,
                friction=1.0) -> int:
        """A box body; mass 0 makes it static."""
        p = self.p
        col = p.createCollisionShape(pb.GEOM_BOX, halfExtents=half_extents)
        vis = p.createVisualShape(pb.GEOM_BOX, halfExtents=half_extents, rgbaColor=self._rgba(color))
        body = p.createMultiBody(mass, col, vis, basePosition=position, baseOrientation=quaternion)
        p.changeDynamics(body, -1, lateralFriction=friction)
        return body

    def add_cylinder(self, radius, height, position, quaternion=(0, 0, 0, 1), color="grey", mass=0.1,
                     friction=1.0) -> int:
        """An upright cylinder body; mass 0 makes it static."""
        p = self.p
        col = p.createCollisionShape(pb.GEOM_CYLINDER, radius=radius, height=height)
        vis = p.createVisualShape(pb.GEOM_CYLINDER, radius=radius, length=height,
                                  rgbaColor=self._rgba(color))
        body = p.createMultiBody(mass, col, vis, basePosition=position, baseOrientation=quaternion)
        p.changeDynamics(body, -1, lateralFriction=friction)
        return body

    def compound_shapes(self, parts):
        """Collision and visual shape ids of a compound made of ``parts``.

        Each part is ``(kind, size, offset, color)`` with kind ``"box"`` (size = half extents)
        or ``"cylinder"`` (size = (radius, height)) or ``"sphere"`` (size = (radius,)).
        """
        p = self.p
        kinds, radii, halfs, lengths, offsets, colors = [], [], [], [], [], []
        for kind, size, offset, _color in parts:
            offsets.append(list(offset))
            if kind == "box":
                kinds.append(pb.GEOM_BOX)
                halfs.append(list(size))
                radii.append(0.0)
                lengths.append(0.0)
            elif kind == "cylinder":
                kinds.append(pb.GEOM_CYLINDER)
                halfs.append([0.0, 0.0, 0.0])
                radii.append(float(size[0]))
                lengths.append(float(size[1]))
            elif kind == "sphere":
                kinds.append(pb.GEOM_SPHERE)
                halfs.append([0.0, 0.0, 0.0])
                radii.append(float(size[0]))
                lengths.append(0.0)
            else:
                raise ValueError(f"unknown compound part kind {kind!r}")
        col = p.createCollisionShapeArray(kinds, radii=radii, halfExtents=halfs, lengths=lengths,
                                          collisionFramePositions=offsets)
        colors = [list(self._rgba(c)) for *_x, c in parts]
        vis = p.createVisualShapeArray(kinds, radii=radii, halfExtents=halfs, lengths=lengths,
                                       rgbaColors=colors, visualFramePositions=offsets)
        return col, vis

    def add_compound(self, parts, position, quaternion=(0, 0, 0, 1), mass=0.0, friction=1.0) -> int:
        """A rigid body made of several primitives (see ``compound_shapes``)."""
        col, vis = self.compound_shapes(parts)
        body = self.p.createMultiBody(mass, col, vis, basePosition=position, baseOrientation=quaternion)
        self.p.changeDynamics(body, -1, lateralFriction=friction)
        return body

    def add_articulated(self, base_parts, position, links, quaternion=(0, 0, 0, 1)) -> int:
        """A static compound base with movable links.

        ``links`` holds dicts with ``parts`` (see ``compound_shapes``), ``parent`` (0 = base,
        i = i-th link, 1-based as pybullet wants), ``offset`` (link frame in the parent frame),
        ``joint`` (``"prismatic"``, ``"revolute"`` or ``"fixed"``), ``axis``, ``mass``,
        and optional ``limits`` (lower, upper).
        """
        p = self.p
        base_col, base_vis = self.compound_shapes(base_parts)
        kinds = {"prismatic": pb.JOINT_PRISMATIC, "revolute": pb.JOINT_REVOLUTE, "fixed": pb.JOINT_FIXED}
        cols, viss = [], []
        for link in links:
            c, v = self.compound_shapes(link["parts"])
            cols.append(c)
            viss.append(v)
        body = p.createMultiBody(
            0.0, base_col, base_vis, basePosition=position, baseOrientation=quaternion,
            linkMasses=[float(link.get("mass", 0.2)) for link in links],
            linkCollisionShapeIndices=cols, linkVisualShapeIndices=viss,
            linkPositions=[list(link["offset"]) for link in links],
            linkOrientations=[[0, 0, 0, 1]] * len(links),
            linkInertialFramePositions=[[0, 0, 0]] * len(links),
            linkInertialFrameOrientations=[[0, 0, 0, 1]] * len(links),
            linkParentIndices=[int(link["parent"]) for link in links],
            linkJointTypes=[kinds[link["joint"]] for link in links],
            linkJointAxis=[list(link.get("axis", (0, 0, 1))) for link in links],
        )
        for j, link in enumerate(links):
            if "limits" in link:
                lo, hi = link["limits"]
                p.changeDynamics(body, j, jointLowerLimit=lo, jointUpperLimit=hi, jointLimitForce=500)
            p.changeDynamics(body, j, lateralFriction=1.0)
        return body

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
