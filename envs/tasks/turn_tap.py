"""turn_tap: turn the left or the right handle of the tap by a quarter turn."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.poses import top_down_quat
from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import HOME_FINGER_YAW, Task, Waypoint
from rdd.registry import register

BODY_TOP = 0.09
HANDLE_Z = 0.03  # handle bar height above its joint
TURNED = np.deg2rad(70)


@register("task", "turn_tap")
class TurnTap(Task):
    """Grasp the named tap handle from above and rotate it a quarter turn."""

    name = "turn_tap"
    order = 6
    description = "turn the left or right tap handle"

    def variations(self):
        """Which handle (left/right as seen by the robot)."""
        return [{"side": "left"}, {"side": "right"}]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Tap body with a spout and two handles on revolute joints."""
        tx, ty = rng.uniform(0.5, 0.58), rng.uniform(-0.12, 0.12)
        base = [
            ("box", (0.04, 0.13, BODY_TOP / 2), (0, 0, BODY_TOP / 2), "grey"),
            ("cylinder", (0.015, 0.08), (-0.05, 0, BODY_TOP - 0.015), "grey"),
        ]
        links = []
        for y in (0.09, -0.09):  # left (+y) first
            links.append({
                "parts": [("cylinder", (0.01, HANDLE_Z), (0, 0, HANDLE_Z / 2), "grey"),
                          ("box", (0.045, 0.009, 0.009), (0, 0, HANDLE_Z), "white")],
                "parent": 0, "offset": (0, y, BODY_TOP), "joint": "revolute", "axis": (0, 0, 1),
                "mass": 0.05, "limits": (-np.pi / 2 - 0.2, np.pi / 2 + 0.2)})
        body = scene.add_articulated(base, (tx, ty, TABLE_TOP), links)
        self.body = body
        for j, side in enumerate(("left", "right")):
            # A weak velocity servo is the valve's friction: the handle stays where it is turned.
            scene.p.setJointMotorControl2(body, j, 0, targetVelocity=0, force=0.3)  # 0 = VELOCITY_CONTROL
            self.add_object(f"{side}_tap_handle", "handle", body, j, color="white",
                            size=(0.09, 0.018, HANDLE_Z),
                            role="target" if side == self.params["side"] else "fixture")
            self.add_articulation(f"{side}_tap", "tap", body, j, 0.0, np.pi / 2)
        scene.fixtures.add(body)

    def goal(self) -> str:
        """E.g. 'turn left tap'."""
        return f"turn {self.params['side']} tap"

    def expert(self) -> Iterator[Waypoint]:
        """Above the handle, grasp across its bar, rotate about the joint axis, release, lift."""
        side = self.params["side"]
        pivot, _ = self.pose(f"{side}_tap_handle")  # link frame = on the joint axis
        bar = pivot + np.array([0, 0, HANDLE_Z])
        # Handle bar lies along x at rest: fingers close across it, along y.
        yaw = np.pi / 2 + np.pi * np.round((HOME_FINGER_YAW - np.pi / 2) / np.pi)
        turn = np.pi / 2 if yaw + np.pi / 2 <= HOME_FINGER_YAW + np.pi else -np.pi / 2
        if yaw + turn > 2.0:  # keep joint 7 inside its range
            turn = -turn
        yield Waypoint(bar + np.array([0, 0, 0.1]), top_down_quat(yaw), True, f"reach for the {side} tap handle")
        yield Waypoint(bar.copy(), top_down_quat(yaw), False, f"grasp the {side} tap handle")
        yield Waypoint(bar.copy(), top_down_quat(yaw + turn), True, f"turn the {side} tap")
        yield Waypoint(bar + np.array([0, 0, 0.1]), top_down_quat(yaw + turn), True, "move the gripper up")

    def success(self) -> bool:
        """The named handle turned by at least 70 degrees, the other one barely moved."""
        other = "right" if self.params["side"] == "left" else "left"
        return bool(abs(self.art_state(f"{self.params['side']}_tap")) >= TURNED
                    and abs(self.art_state(f"{other}_tap")) < np.deg2rad(20))
