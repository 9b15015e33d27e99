"""put_item_in_drawer: open the named drawer and put the block from the cabinet top inside."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.poses import top_down_quat
from envs.scene import Scene
from envs.tasks.base import HOME_FINGER_YAW, Task, Waypoint, yaw_of
from envs.tasks.cabinet import (
    CAB_X,
    CAB_Y,
    CAB_YAW,
    DEPTH,
    DRAWER_H,
    build_cabinet,
    pull_drawer_waypoints,
)
from rdd.registry import register

ITEM_HALF = 0.02


@register("task", "put_item_in_drawer")
class PutItemInDrawer(Task):
    """Open the named drawer, pick the item from the cabinet top, drop it in the drawer."""

    name = "put_item_in_drawer"
    order = 2
    description = "open the named drawer and put the item in it"

    def variations(self):
        """Which drawer."""
        return [{"drawer": d} for d in ("top", "middle", "bottom")]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Cabinet to one side, drawers facing the robot diagonally, with a block on its top."""
        side = rng.choice([-1.0, 1.0])
        cab = build_cabinet(scene, self, rng.uniform(CAB_X[0], CAB_X[1]), side * rng.uniform(CAB_Y[0], CAB_Y[1]),
                            side * CAB_YAW, target=self.params["drawer"])
        self.cabinet = cab
        # The item lies turned by up to +-0.5 rad from the cabinet's own heading (RLBench keeps it
        # at one fixed pose on the cabinet). Measured from the cabinet, not the world: from the
        # world, item yaw 0 sat exactly where the grasp nearest "across the drawer" jumps by a
        # quarter turn, so the expert's grasp flipped on the sign of a small yaw, which a policy
        # cannot learn from a few demos (it fell between the two and hit the cabinet).
        yaw = side * CAB_YAW + rng.uniform(-0.5, 0.5)
        pos = cab.to_world((rng.uniform(0.05, 0.08), rng.uniform(-0.05, 0.05), cab.top_z + ITEM_HALF))
        item = scene.add_box((ITEM_HALF,) * 3, pos, scene.p.getQuaternionFromEuler((0, 0, yaw)),
                             color="purple", mass=0.05)
        self.add_object("item", "block", item, color="purple", size=(2 * ITEM_HALF,) * 3, role="target")

    def goal(self) -> str:
        """E.g. 'put the item in the top drawer'."""
        return f"put the item in the {self.params['drawer']} drawer"

    def _tray(self) -> np.ndarray:
        """Centre of the named drawer's tray floor (world)."""
        d = self.params["drawer"]
        handle, _ = self.pose(f"{d}_drawer_handle")
        opening = self.art_state(f"{d}_drawer")
        # Near the drawer's front panel: the wrist, further out than the hand, must clear the
        # handles of the closed drawers above.
        return self.cabinet.to_world((-opening + 0.055, 0.0, handle[2] - DRAWER_H / 2 + 0.01))

    def expert(self) -> Iterator[Waypoint]:
        """Open the drawer, then pick the item and drop it in the tray."""
        d = self.params["drawer"]
        # open_drawer's pull: the same instruction then means the same motion in both tasks (a
        # longer pull here left 1.5 cm to the drawer's end stop, and its hand orientation, chosen
        # by reachability at the pull's midpoint, differed from open_drawer's on the same cabinet)
        yield from pull_drawer_waypoints(self, self.cabinet, d)
        pos, orn = self.pose("item")
        # Fingers across the drawer, so the hand's long side clears the cabinet front.
        w = self.cabinet.width_direction
        across = np.arctan2(w[1], w[0])
        across += np.pi * np.round((HOME_FINGER_YAW - across) / np.pi)
        yaw = yaw_of(orn) + np.pi / 2 * np.round((across - yaw_of(orn)) / (np.pi / 2))
        # Turn the hand down while clear of the cabinet, before reaching over its top, fingers
        # across the drawer: a yaw fixed in the cabinet's frame (the drawer handle's), where the
        # item's yaw made it depend on an object the hand is not at, and the hand's own yaw frame
        # flips with the pull's finger sense (a policy then predicted it a half turn off).
        ee = self.scene.ee_pose()
        ready = np.array([ee[0], ee[1], self.cabinet.top_z + 0.12])
        yield Waypoint(ready, top_down_quat(across), True, "move the gripper above the cabinet")
        yield from self.pick("item", pos, yaw, float(pos[2]), above=0.08, lift_z=float(pos[2]) + 0.1)
        tray = self._tray()
        # Let go a few centimetres up, so the hand stays above the drawer front panel.
        release = tray + np.array([0, 0, ITEM_HALF + 0.04])
        # Carry at the cabinet-top height, then lower straight into the tray.
        above = self.cabinet.top_z + 0.12 - release[2]
        yield from self.carry("item", "item", f"{d} drawer", release, above=above, preposition="in")

    def success(self) -> bool:
        """The item rests inside the named drawer's tray, released."""
        if self.scene.held is not None:
            return False
        pos, _ = self.pose("item")
        tray = self._tray()
        d = pos - tray
        depth = -float(d[:2] @ self.cabinet.pull_direction[:2])  # into the drawer
        across = float(d[:2] @ self.cabinet.width_direction[:2])
        inside = -0.04 < depth < DEPTH - 0.06 and abs(across) < 0.1
        return bool(inside and abs(d[2] - ITEM_HALF) < 0.02)
