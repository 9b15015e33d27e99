"""A three-drawer cabinet (top / middle / bottom) whose drawers slide toward the robot."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from envs.scene import Scene
from envs.tasks.base import Task

DRAWERS = ("bottom", "middle", "top")
DRAWER_H = 0.09
BASE_Z = 0.02
DEPTH = 0.2
HALF_W = 0.12
TRAVEL = 0.2
HANDLE_STANDOFF = 0.035
# Where the front centre of a cabinet goes (x range, |y| range) and how far it is turned
# toward the workspace centre (so the front camera sees drawers slide out).
CAB_X = (0.53, 0.58)
CAB_Y = (0.13, 0.17)
CAB_YAW = np.pi / 4


@dataclass
class Cabinet:
    """Ids and geometry of a built cabinet; drawer joint i has handle link ``2 i + 1``."""

    body: int
    front_x: float
    y: float
    yaw: float = 0.0  # 0: drawers face -x (toward the robot); +-pi/2: they face the workspace centre

    def to_world(self, local) -> np.ndarray:
        """World point of a point in the cabinet frame (x into the cabinet, origin at the front)."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        x, y, z = local
        return np.array([self.front_x + c * x - s * y, self.y + s * x + c * y, z])

    @property
    def pull_direction(self) -> np.ndarray:
        """Unit vector a drawer moves along when opened (world)."""
        return np.array([-np.cos(self.yaw), -np.sin(self.yaw), 0.0])

    @property
    def width_direction(self) -> np.ndarray:
        """Unit vector across the drawers (world)."""
        return np.array([-np.sin(self.yaw), np.cos(self.yaw), 0.0])

    def drawer_joint(self, name: str) -> int:
        """Prismatic joint index of drawer ``name``."""
        return 2 * DRAWERS.index(name)

    def handle_link(self, name: str) -> int:
        """Link index of drawer ``name``'s handle."""
        return 2 * DRAWERS.index(name) + 1

    @staticmethod
    def drawer_z(name: str) -> float:
        """Height of the drawer's centre (and its handle)."""
        return BASE_Z + DRAWER_H / 2 + DRAWER_H * DRAWERS.index(name)

    @property
    def top_z(self) -> float:
        """Height of the cabinet's top surface."""
        return BASE_Z + 3 * DRAWER_H + 0.015


def build_cabinet(scene: Scene, task: Task, front_x: float, y: float, yaw: float = 0.0,
                  target: str | None = None) -> Cabinet:
    """Create the cabinet (front centre at (front_x, y), turned by ``yaw``), and register its
    handles (objects; the ``target`` drawer's handle has role "target") and drawers
    (articulations)."""
    top = BASE_Z + 3 * DRAWER_H
    shell = [
        ("box", (DEPTH / 2, 0.006, top / 2 + 0.0075), (DEPTH / 2, HALF_W + 0.006, top / 2 + 0.0075), "white"),
        ("box", (DEPTH / 2, 0.006, top / 2 + 0.0075), (DEPTH / 2, -HALF_W - 0.006, top / 2 + 0.0075), "white"),
        ("box", (0.006, HALF_W + 0.012, top / 2 + 0.0075), (DEPTH + 0.006, 0, top / 2 + 0.0075), "white"),
        ("box", (DEPTH / 2 + 0.006, HALF_W + 0.012, 0.0075), (DEPTH / 2, 0, top + 0.0075), "white"),
        ("box", (DEPTH / 2, HALF_W, BASE_Z / 2), (DEPTH / 2, 0, BASE_Z / 2), "white"),
    ]
    links = []
    fronts = {"bottom": "wood", "middle": "wood", "top": "wood"}
    for i, name in enumerate(DRAWERS):
        zc = BASE_Z + DRAWER_H / 2 + DRAWER_H * i
        h = DRAWER_H / 2 - 0.003
        tray = [
            ("box", (0.005, HALF_W - 0.003, h), (-0.005, 0, 0), fronts[name]),
            ("box", (DEPTH / 2 - 0.01, HALF_W - 0.012, 0.004), (DEPTH / 2 - 0.01, 0, -h + 0.004), "grey"),
            ("box", (DEPTH / 2 - 0.01, 0.004, h * 0.6), (DEPTH / 2 - 0.01, HALF_W - 0.012, -h * 0.4), "grey"),
            ("box", (DEPTH / 2 - 0.01, 0.004, h * 0.6), (DEPTH / 2 - 0.01, -HALF_W + 0.012, -h * 0.4), "grey"),
            ("box", (0.004, HALF_W - 0.012, h * 0.6), (DEPTH - 0.02, 0, -h * 0.4), "grey"),
        ]
        links.append({"parts": tray, "parent": 0, "offset": (0, 0, zc), "joint": "prismatic",
                      "axis": (-1, 0, 0), "mass": 0.5, "limits": (0.0, TRAVEL)})
        handle = [
            ("box", (0.006, 0.006, 0.026), (0, 0, 0), "black"),
            ("box", (0.0145, 0.005, 0.004), (0.0205, 0, 0.02), "black"),
            ("box", (0.0145, 0.005, 0.004), (0.0205, 0, -0.02), "black"),
        ]
        links.append({"parts": handle, "parent": 2 * i + 1, "offset": (-HANDLE_STANDOFF, 0, 0),
                      "joint": "fixed", "mass": 0.05})
    quat = scene.p.getQuaternionFromEuler((0, 0, yaw))
    body = scene.add_articulated(shell, (front_x, y, 0.0), links, quaternion=quat)
    cab = Cabinet(body, front_x, y, yaw)
    for name in DRAWERS:
        j = cab.drawer_joint(name)
        # A weak velocity motor acts as sliding friction: a drawer stays where it is left.
        scene.p.setJointMotorControl2(body, j, 1, targetVelocity=0, force=3.0)  # 1 = VELOCITY_CONTROL
        task.add_object(f"{name}_drawer_handle", "handle", body, cab.handle_link(name), color="black",
                        size=(0.012, 0.012, 0.052), role="target" if name == target else "fixture")
        task.add_articulation(f"{name}_drawer", "drawer", body, j, 0.0, TRAVEL)
    scene.fixtures.add(body)
    return cab


def pull_drawer_waypoints(task: Task, cab: Cabinet, name: str, distance: float = 0.17):
    """Reach, grasp the handle, pull the drawer open (releasing there), back away: 4 segments."""
    from envs.tasks.base import Waypoint

    handle, _ = task.pose(f"{name}_drawer_handle")
    n = cab.pull_direction
    quat = task.scene.best_side_quat(handle + n * distance / 2, approach=-n)
    pre = handle + 0.1 * n
    pulled = handle + distance * n
    return [
        Waypoint(pre, quat, True, f"reach for the {name} drawer handle"),
        Waypoint(handle.copy(), quat, False, f"grasp the {name} drawer handle"),
        Waypoint(pulled, quat, True, f"pull the {name} drawer open"),
        Waypoint(pulled + 0.07 * n, quat, True, "move the gripper away from the handle"),
    ]
