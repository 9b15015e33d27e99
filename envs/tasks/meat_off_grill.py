"""meat_off_grill: take the steak or the chicken off the grill and put it on the plate."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import Task, Waypoint, grasp_yaw, yaw_of
from rdd.registry import register

GRILL_TOP = 0.068
MEATS = {
    # name: (shape, size, colour)
    "steak": ("box", (0.04, 0.027, 0.011), "brown"),
    "chicken": ("cylinder", (0.027, 0.03), "pink"),
}


@register("task", "meat_off_grill")
class MeatOffGrill(Task):
    """Pick the named meat from the grill and place it on the plate."""

    name = "meat_off_grill"
    order = 4
    description = "take the named meat off the grill and put it on the plate"

    def variations(self):
        """Which meat."""
        return [{"meat": m} for m in MEATS]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Grill on one side, plate on the other, both meats on the grill."""
        side = rng.choice([-1.0, 1.0])
        gx, gy = rng.uniform(0.46, 0.56), side * rng.uniform(0.1, 0.17)
        parts = [("box", (0.08, 0.13, 0.03), (0, 0, 0.03), "black")]
        for k in range(6):
            parts.append(("box", (0.08, 0.004, 0.004), (0, -0.11 + 0.044 * k, 0.064), "grey"))
        grill = scene.add_compound(parts, (gx, gy, TABLE_TOP))
        self.add_object("grill", "grill", grill, color="black", size=(0.16, 0.26, 0.068), role="fixture")
        px, py = rng.uniform(0.4, 0.55), -side * rng.uniform(0.12, 0.22)
        plate = scene.add_cylinder(0.065, 0.01, (px, py, TABLE_TOP + 0.005), color="white", mass=0)
        self.add_object("plate", "plate", plate, color="white", size=(0.13, 0.13, 0.01), role="target")
        order = list(MEATS) if rng.random() < 0.5 else list(MEATS)[::-1]
        for k, meat in enumerate(order):
            kind, size, color = MEATS[meat]
            yaw = rng.uniform(-0.4, 0.4)
            q = scene.p.getQuaternionFromEuler((0, 0, yaw))
            pos = (gx + rng.uniform(-0.015, 0.015), gy + (-0.06 if k == 0 else 0.06), GRILL_TOP + 0.016)
            if kind == "box":
                body = scene.add_box(size, pos, q, color=color, mass=0.1)
                dims = tuple(2 * s for s in size)
            else:
                body = scene.add_cylinder(size[0], size[1], pos, q, color=color, mass=0.1)
                dims = (2 * size[0], 2 * size[0], size[1])
            self.add_object(meat, meat, body, color=color, size=dims,
                            role="target" if meat == self.params["meat"] else "distractor")

    def goal(self) -> str:
        """E.g. 'take the steak off the grill'."""
        return f"take the {self.params['meat']} off the grill"

    def expert(self) -> Iterator[Waypoint]:
        """Pick the meat (fingers across its short side) and place it on the plate."""
        meat = self.params["meat"]
        pos, orn = self.pose(meat)
        yaw = grasp_yaw(yaw_of(orn) + np.pi / 2, np.pi) if meat == "steak" else grasp_yaw(0.0, np.pi)
        yield from self.pick(meat, pos, yaw, float(pos[2]) + 0.004, lift_z=0.22)
        plate, _ = self.pose("plate")
        yield from self.carry(meat, meat, "plate", plate + np.array([0, 0, 0.03]))

    def success(self) -> bool:
        """The meat lies on the plate, released."""
        if self.scene.held is not None:
            return False
        pos, _ = self.pose(self.params["meat"])
        plate, _ = self.pose("plate")
        return bool(np.linalg.norm(pos[:2] - plate[:2]) < 0.05 and pos[2] < 0.05)
