"""insert_onto_square_peg: put the square ring on the peg of the named colour (pretraining task)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import HOME_FINGER_YAW, Task, Waypoint, yaw_of
from rdd.registry import register

COLORS = ("red", "green", "blue")
RING_HALF, BAR, RING_H = 0.06, 0.02, 0.03
PEG_HALF, PEG_H = 0.012, 0.1


@register("task", "insert_onto_square_peg")
class InsertOntoSquarePeg(Task):
    """Pick the square ring by one side and slide it down over the named peg."""

    name = "insert_onto_square_peg"
    order = 9
    pretraining = True
    description = "put the square ring on the peg of the named colour"

    def variations(self):
        """Colour of the target peg."""
        return [{"color": c} for c in COLORS]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Three pegs in a row on a base, the ring on the table beside them."""
        side = rng.choice([-1.0, 1.0])
        bx, by = rng.uniform(0.5, 0.6), side * rng.uniform(0.1, 0.16)
        order = [COLORS[i] for i in rng.permutation(len(COLORS))]
        base = scene.add_box((0.04, 0.17, 0.005), (bx, by, TABLE_TOP + 0.005), color="wood", mass=0)
        self.add_object("peg_base", "base", base, color="wood", size=(0.08, 0.34, 0.01), role="fixture")
        for k, c in enumerate(order):
            body = scene.add_box((PEG_HALF, PEG_HALF, PEG_H / 2), (bx, by + (k - 1) * 0.12, PEG_H / 2), color=c, mass=0)
            self.add_object(f"{c}_peg", "peg", body, color=c, size=(2 * PEG_HALF, 2 * PEG_HALF, PEG_H),
                            role="target" if c == self.params["color"] else "distractor")
        c0 = RING_HALF - BAR / 2
        parts = [
            ("box", (RING_HALF, BAR / 2, RING_H / 2), (0, c0, 0), "orange"),
            ("box", (RING_HALF, BAR / 2, RING_H / 2), (0, -c0, 0), "orange"),
            ("box", (BAR / 2, RING_HALF - BAR, RING_H / 2), (c0, 0, 0), "orange"),
            ("box", (BAR / 2, RING_HALF - BAR, RING_H / 2), (-c0, 0, 0), "orange"),
        ]
        rx, ry = rng.uniform(0.38, 0.5), -side * rng.uniform(0.08, 0.2)
        yaw = rng.uniform(-0.5, 0.5)
        ring = scene.add_compound(parts, (rx, ry, TABLE_TOP + RING_H / 2),
                                  scene.p.getQuaternionFromEuler((0, 0, yaw)), mass=0.1)
        self.add_object("square_ring", "ring", ring, color="orange", size=(2 * RING_HALF, 2 * RING_HALF, RING_H),
                        role="target")

    def goal(self) -> str:
        """E.g. 'put the ring on the red peg'."""
        return f"put the ring on the {self.params['color']} peg"

    def expert(self) -> Iterator[Waypoint]:
        """Grasp the ring side whose radial direction suits the wrist; lower it over the peg."""
        ring, orn = self.pose("square_ring")
        yaw0 = yaw_of(orn)
        best = None
        for k in range(4):
            theta = yaw0 + k * np.pi / 2
            # Fingers close radially across the bar: finger yaw = theta (mod pi).
            fy = theta + np.pi * np.round((HOME_FINGER_YAW - theta) / np.pi)
            bar = ring + (RING_HALF - BAR / 2) * np.array([np.cos(theta), np.sin(theta), 0.0])
            # Prefer the side nearest the robot, then the wrist's comfortable yaw.
            score = bar[0] + 0.05 * abs(fy - HOME_FINGER_YAW)
            if best is None or score < best[0]:
                best = (score, bar, fy)
        _, bar, fy = best
        yield from self.pick("square ring", bar, fy, TABLE_TOP + RING_H / 2 + 0.006, lift_z=0.26)
        peg, _ = self.pose(f"{self.params['color']}_peg")
        # Let go once the ring encircles the peg's top (the hand, wide along the finger axis,
        # must stay above the peg); the ring then slides down the peg.
        target = np.array([peg[0], peg[1], TABLE_TOP + PEG_H - 0.025])
        yield from self.carry("square_ring", "square ring", f"{self.params['color']} peg", target,
                              above=PEG_H + 0.04)

    def success(self) -> bool:
        """The ring encircles the named peg near its foot, released."""
        if self.scene.held is not None:
            return False
        ring, _ = self.pose("square_ring")
        peg, _ = self.pose(f"{self.params['color']}_peg")
        return bool(np.linalg.norm(ring[:2] - peg[:2]) < RING_HALF - BAR - PEG_HALF + 0.003 and ring[2] < 0.06)
