"""light_bulb_in: put the bulb of the named colour into the lamp's socket (pretraining task)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import Task, Waypoint, grasp_yaw, sample_positions
from rdd.registry import register

COLORS = ("red", "green", "blue", "yellow")
LAMP_TOP = 0.08  # top of the lamp body = floor of the socket
SOCKET_H = 0.03
BULB_BASE_R, BULB_BASE_H, GLASS_R = 0.016, 0.04, 0.028


@register("task", "light_bulb_in")
class LightBulbIn(Task):
    """Pick the named bulb by its glass and lower its base into the socket."""

    name = "light_bulb_in"
    order = 10
    pretraining = True
    description = "put the light bulb of the named colour into the lamp"

    def variations(self):
        """Colour of the bulb."""
        return [{"color": c} for c in COLORS]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """A lamp with a square socket and two bulbs."""
        color = self.params["color"]
        others = [c for c in COLORS if c != color]
        other = others[int(rng.integers(len(others)))]
        xy = sample_positions(rng, 3, (0.38, 0.6), (-0.25, 0.25), 0.14)
        s = 0.022 + 0.006  # socket hole half width + half wall
        parts = [
            ("box", (0.05, 0.05, LAMP_TOP / 2), (0, 0, LAMP_TOP / 2), "black"),
            ("box", (0.034, 0.006, SOCKET_H / 2), (0, s, LAMP_TOP + SOCKET_H / 2), "grey"),
            ("box", (0.034, 0.006, SOCKET_H / 2), (0, -s, LAMP_TOP + SOCKET_H / 2), "grey"),
            ("box", (0.006, 0.022, SOCKET_H / 2), (s, 0, LAMP_TOP + SOCKET_H / 2), "grey"),
            ("box", (0.006, 0.022, SOCKET_H / 2), (-s, 0, LAMP_TOP + SOCKET_H / 2), "grey"),
        ]
        lamp = scene.add_compound(parts, (*xy[0], TABLE_TOP))
        self.add_object("lamp", "lamp", lamp, color="black", size=(0.1, 0.1, LAMP_TOP + SOCKET_H), role="target")
        for c, p in zip((color, other), xy[1:], strict=True):
            bulb = scene.add_compound([
                ("cylinder", (BULB_BASE_R, BULB_BASE_H), (0, 0, BULB_BASE_H / 2), "grey"),
                ("sphere", (GLASS_R,), (0, 0, BULB_BASE_H + GLASS_R - 0.003), c),
            ], (*p, TABLE_TOP), mass=0.05)
            self.add_object(f"{c}_bulb", "light bulb", bulb, color=c,
                            size=(2 * GLASS_R, 2 * GLASS_R, BULB_BASE_H + 2 * GLASS_R),
                            role="target" if c == color else "distractor")

    def goal(self) -> str:
        """E.g. 'screw in the red light bulb'."""
        return f"screw in the {self.params['color']} light bulb"

    def expert(self) -> Iterator[Waypoint]:
        """Pick the bulb by the glass, lower its base into the socket."""
        name = f"{self.params['color']}_bulb"
        label = f"{self.params['color']} light bulb"
        pos, _ = self.pose(name)
        yaw = grasp_yaw(0.0, np.pi)
        yield from self.pick(label, pos, yaw, float(pos[2]) + BULB_BASE_H + GLASS_R - 0.003, lift_z=0.28)
        lamp, _ = self.pose("lamp")
        target = np.array([lamp[0], lamp[1], LAMP_TOP + 0.004])
        yield from self.carry(name, label, "lamp", target, above=0.07, preposition="into")

    def success(self) -> bool:
        """The bulb stands in the socket, released."""
        if self.scene.held is not None:
            return False
        pos, orn = self.pose(f"{self.params['color']}_bulb")
        lamp, _ = self.pose("lamp")
        upright = abs(np.array(self.scene.p.getMatrixFromQuaternion(orn))[8]) > 0.95
        return bool(np.linalg.norm(pos[:2] - lamp[:2]) < 0.015 and abs(pos[2] - LAMP_TOP) < 0.02 and upright)
