"""close_jar: put the lid on the jar of the named colour (planner pretraining task)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import Task, Waypoint, grasp_yaw, sample_positions
from rdd.registry import register

COLORS = ("red", "green", "blue", "yellow")
JAR_R, JAR_H = 0.035, 0.09
LID_R, LID_H = 0.038, 0.025


@register("task", "close_jar")
class CloseJar(Task):
    """Pick up the lid and put it on the named jar."""

    name = "close_jar"
    order = 8
    pretraining = True
    description = "close the jar of the named colour with the lid"

    def variations(self):
        """Colour of the jar to close."""
        return [{"color": c} for c in COLORS]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Two jars (target and distractor colour) and a lid."""
        color = self.params["color"]
        others = [c for c in COLORS if c != color]
        other = others[int(rng.integers(len(others)))]
        xy = sample_positions(rng, 3, (0.38, 0.6), (-0.25, 0.25), 0.13)
        for c, p in zip((color, other), xy[:2], strict=True):
            body = scene.add_cylinder(JAR_R, JAR_H, (*p, TABLE_TOP + JAR_H / 2), color=c, mass=1.0)
            self.add_object(f"{c}_jar", "jar", body, color=c, size=(2 * JAR_R, 2 * JAR_R, JAR_H),
                            role="target" if c == color else "distractor")
        lid = scene.add_cylinder(LID_R, LID_H, (*xy[2], TABLE_TOP + LID_H / 2), color="grey", mass=0.05)
        self.add_object("lid", "lid", lid, color="grey", size=(2 * LID_R, 2 * LID_R, LID_H), role="target")

    def goal(self) -> str:
        """E.g. 'close the red jar'."""
        return f"close the {self.params['color']} jar"

    def expert(self) -> Iterator[Waypoint]:
        """Pick the lid and lower it onto the jar."""
        lid, _ = self.pose("lid")
        yaw = grasp_yaw(0.0, np.pi)
        yield from self.pick("lid", lid, yaw, TABLE_TOP + 0.018, lift_z=0.24)
        jar, _ = self.pose(f"{self.params['color']}_jar")
        top = np.array([jar[0], jar[1], TABLE_TOP + JAR_H + LID_H / 2 + 0.004])
        yield from self.carry("lid", "lid", f"{self.params['color']} jar", top)

    def success(self) -> bool:
        """The lid sits on top of the named jar, released."""
        if self.scene.held is not None:
            return False
        lid, _ = self.pose("lid")
        jar, _ = self.pose(f"{self.params['color']}_jar")
        top = jar[2] + JAR_H / 2 + LID_H / 2
        return bool(np.linalg.norm(lid[:2] - jar[:2]) < 0.015 and abs(lid[2] - top) < 0.012)
