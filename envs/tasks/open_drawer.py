"""open_drawer: open the top, middle or bottom drawer of the cabinet."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import Scene
from envs.tasks.base import Task, Waypoint
from envs.tasks.cabinet import CAB_X, CAB_Y, CAB_YAW, DRAWERS, build_cabinet, pull_drawer_waypoints
from rdd.registry import register

OPEN_ENOUGH = 0.12


@register("task", "open_drawer")
class OpenDrawer(Task):
    """Grasp the named drawer's handle and pull it open."""

    name = "open_drawer"
    order = 1
    description = "open the named drawer of a three-drawer cabinet"

    def variations(self):
        """Which drawer."""
        return [{"drawer": d} for d in ("top", "middle", "bottom")]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """A cabinet on the left or right of the workspace, drawers facing the robot diagonally."""
        side = rng.choice([-1.0, 1.0])
        self.cabinet = build_cabinet(scene, self, rng.uniform(CAB_X[0], CAB_X[1]),
                                     side * rng.uniform(CAB_Y[0], CAB_Y[1]), side * CAB_YAW, target=self.params["drawer"])

    def goal(self) -> str:
        """E.g. 'open the top drawer'."""
        return f"open the {self.params['drawer']} drawer"

    def expert(self) -> Iterator[Waypoint]:
        """Pull the named drawer by its handle."""
        yield from pull_drawer_waypoints(self, self.cabinet, self.params["drawer"])

    def success(self) -> bool:
        """The named drawer is open by at least 12 cm, the others stay shut."""
        for d in DRAWERS:
            opening = self.art_state(f"{d}_drawer")
            if d == self.params["drawer"] and opening < OPEN_ENOUGH:
                return False
            if d != self.params["drawer"] and opening > 0.05:
                return False
        return True
