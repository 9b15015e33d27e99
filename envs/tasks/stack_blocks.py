"""stack_blocks: stack the blocks of the named colour on the plate (colour and count vary)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import HOME_FINGER_YAW, Task, Waypoint, grasp_yaw, sample_positions, yaw_of
from rdd.registry import register

HALF = 0.025
COLORS = ("red", "green", "blue", "yellow")
WORDS = {2: "two", 3: "three"}


@register("task", "stack_blocks")
class StackBlocks(Task):
    """Pick N blocks of one colour (among distractors) and stack them on the plate."""

    name = "stack_blocks"
    order = 3
    description = "stack N blocks of the named colour on the grey plate"

    def variations(self):
        """Colour x count."""
        return [{"color": c, "count": n} for n in (2, 3) for c in COLORS]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Plate plus N target blocks and two distractor blocks, randomly placed."""
        color, count = self.params["color"], self.params["count"]
        others = [c for c in COLORS if c != color]
        distractors = [others[i] for i in rng.choice(len(others), size=2, replace=False)]
        xy = sample_positions(rng, count + 3, (0.35, 0.62), (-0.27, 0.27), 0.11)
        plate_xy = xy[0]
        plate = scene.add_box((0.05, 0.05, 0.005), (*plate_xy, TABLE_TOP + 0.005), color="grey", mass=0)
        self.plate_top = TABLE_TOP + 0.01
        self.add_object("plate", "plate", plate, color="grey", size=(0.1, 0.1, 0.01), role="target")
        self.targets = []
        for i, p in enumerate(xy[1:]):
            c = color if i < count else distractors[i - count]
            # A full quarter turn of yaws (a cube looks the same every quarter turn), centred on
            # the home finger yaw: centred on 0, the grasp nearest the home yaw jumped by a
            # quarter turn on the sign of a small yaw, which a policy cannot learn from few demos.
            yaw = HOME_FINGER_YAW + rng.uniform(-np.pi / 4, np.pi / 4)
            q = scene.p.getQuaternionFromEuler((0, 0, yaw))
            body = scene.add_box((HALF,) * 3, (*p, TABLE_TOP + HALF), q, color=c, mass=0.1)
            name = f"{c}_block_{i}" if i < count else f"{c}_block"
            self.add_object(name, "block", body, color=c, size=(2 * HALF,) * 3,
                            role="target" if i < count else "distractor")
            if i < count:
                self.targets.append(name)

    def goal(self) -> str:
        """E.g. 'stack two red blocks on the plate'."""
        return f"stack {WORDS[self.params['count']]} {self.params['color']} blocks on the plate"

    def expert(self) -> Iterator[Waypoint]:
        """Pick each target block in turn and put it on top of the growing stack."""
        color = self.params["color"]
        plate_pos, _ = self.pose("plate")
        for level, name in enumerate(self.targets):
            pos, orn = self.pose(name)
            yaw = grasp_yaw(yaw_of(orn))
            label = f"{color} block"
            yield from self.pick(label, pos, yaw, TABLE_TOP + HALF)
            dest = "plate" if level == 0 else f"stack of {color} blocks"
            z = self.plate_top + HALF + level * 2 * HALF + 0.004
            yield from self.place(label, dest, plate_pos, yaw, z)

    def success(self) -> bool:
        """All target blocks rest on the plate, one per level, none held."""
        if self.scene.held is not None:
            return False
        plate_pos, _ = self.pose("plate")
        zs = []
        for name in self.targets:
            pos, _ = self.pose(name)
            if np.linalg.norm(pos[:2] - plate_pos[:2]) > 0.03:
                return False
            zs.append(pos[2])
        expected = self.plate_top + HALF + 2 * HALF * np.arange(len(zs))
        return bool(np.all(np.abs(np.sort(zs) - expected) < 0.012))
