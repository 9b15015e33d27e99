"""stack_cups: stack the other cups on the cup of the named colour (planner pretraining task).

Where each step goes is only in the image: the goal names the base cup, not the other two, and
they are stacked in the order they stand along the table (one side of the front view to the
other), so which cup to reach for, and after "lift the C cup" whether it goes onto the base cup or
onto the cup already standing there, are read from the scene. A base pretrained on it has to read
what stands where, and on what.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import Task, Waypoint, grasp_yaw, sample_positions

COLORS = ("red", "green", "blue", "yellow")
CUP_R, CUP_H = 0.028, 0.05


class StackCups(Task):
    """Pick the two other cups in turn and stack each on top of the named cup."""

    name = "stack_cups"
    pretraining = True
    description = "stack the other two cups on the cup of the named colour"

    def variations(self):
        """Colour of the base cup."""
        return [{"color": c} for c in COLORS]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """The base cup and two cups of two other colours, all placed at random."""
        color = self.params["color"]
        others = [c for c in COLORS if c != color]
        movers = [others[i] for i in rng.choice(len(others), size=2, replace=False)]
        xy = sample_positions(rng, 3, (0.36, 0.62), (-0.25, 0.25), 0.13)
        # the base stands fixed, like stack_blocks' plate, so the stack never topples with it
        base = scene.add_cylinder(CUP_R, CUP_H, (*xy[0], TABLE_TOP + CUP_H / 2), color=color, mass=0.0)
        self.add_object(f"{color}_cup", "cup", base, color=color, size=(2 * CUP_R, 2 * CUP_R, CUP_H),
                        role="target")
        for c, p in zip(movers, xy[1:], strict=True):
            body = scene.add_cylinder(CUP_R, CUP_H, (*p, TABLE_TOP + CUP_H / 2), color=c, mass=0.1)
            self.add_object(f"{c}_cup", "cup", body, color=c, size=(2 * CUP_R, 2 * CUP_R, CUP_H),
                            role="target")
        self.order = [c for _, c in sorted(zip((p[1] for p in xy[1:]), movers, strict=True))]

    def goal(self) -> str:
        """E.g. 'stack the other cups on the red cup'."""
        return f"stack the other cups on the {self.params['color']} cup"

    def expert(self) -> Iterator[Waypoint]:
        """Each other cup onto the top of the growing stack: the base cup, then the cup on it."""
        base, _ = self.pose(f"{self.params['color']}_cup")
        top = self.params["color"]
        yaw = grasp_yaw(0.0, np.pi / 2)
        for level, c in enumerate(self.order):
            pos, _ = self.pose(f"{c}_cup")
            yield from self.pick(f"{c} cup", pos, yaw, TABLE_TOP + CUP_H / 2)
            z = TABLE_TOP + CUP_H * (level + 1.5) + 0.004
            yield from self.place(f"{c} cup", f"{top} cup", base, yaw, z)
            top = c

    def success(self) -> bool:
        """The two other cups stand on the base cup, one per level, none held."""
        if self.scene.held is not None:
            return False
        base, _ = self.pose(f"{self.params['color']}_cup")
        zs = []
        for c in self.order:
            pos, _ = self.pose(f"{c}_cup")
            if np.linalg.norm(pos[:2] - base[:2]) > 0.02:
                return False
            zs.append(pos[2])
        expected = TABLE_TOP + CUP_H * (np.arange(len(zs)) + 1.5)
        return bool(np.all(np.abs(np.sort(zs) - expected) < 0.012))
