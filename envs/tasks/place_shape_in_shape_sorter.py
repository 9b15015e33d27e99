"""place_shape_in_shape_sorter: drop the named shape through its hole in the sorter box."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import Task, Waypoint, grasp_yaw, sample_positions, yaw_of
from rdd.registry import register

PLATE_Z = 0.12  # top of the sorter's lid
HALF_X, HALF_Y = 0.06, 0.15
# shape: (kind, size, colour, hole half extents (x, y), finger symmetry)
SHAPES = {
    "cube": ("box", (0.02, 0.02, 0.02), "red", (0.028, 0.028)),
    "cylinder": ("cylinder", (0.02, 0.04), "green", (0.028, 0.028)),
    "cuboid": ("box", (0.032, 0.018, 0.02), "blue", (0.041, 0.027)),
}
HOLE_Y = {"cube": -0.09, "cylinder": 0.0, "cuboid": 0.09}


@register("task", "place_shape_in_shape_sorter")
class PlaceShapeInShapeSorter(Task):
    """Pick the named shape and drop it through the matching hole of the sorter."""

    name = "place_shape_in_shape_sorter"
    order = 7
    description = "put the named shape into the shape sorter"

    def variations(self):
        """Which shape."""
        return [{"shape": s} for s in SHAPES]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Sorter box (lid with three holes) and the three shapes on the table."""
        side = rng.choice([-1.0, 1.0])
        sx, sy = rng.uniform(0.55, 0.62), side * rng.uniform(0.1, 0.15)
        t = 0.005
        parts = [
            ("box", (HALF_X, 0.004, PLATE_Z / 2), (0, HALF_Y, PLATE_Z / 2), "yellow"),
            ("box", (HALF_X, 0.004, PLATE_Z / 2), (0, -HALF_Y, PLATE_Z / 2), "yellow"),
            ("box", (0.004, HALF_Y, PLATE_Z / 2), (HALF_X, 0, PLATE_Z / 2), "yellow"),
            ("box", (0.004, HALF_Y, PLATE_Z / 2), (-HALF_X, 0, PLATE_Z / 2), "yellow"),
        ]
        edges = [-HALF_Y]
        for shape in SHAPES:
            hx, hy = SHAPES[shape][3]
            yc = HOLE_Y[shape]
            edges += [yc - hy, yc + hy]
            for sgn in (-1, 1):  # lid strips beside the hole
                w = (HALF_X - hx) / 2
                parts.append(("box", (w, hy, t), (sgn * (hx + w), yc, PLATE_Z - t), "orange"))
        edges.append(HALF_Y)
        for a, b in zip(edges[::2], edges[1::2], strict=True):  # lid strips between holes
            parts.append(("box", (HALF_X, (b - a) / 2, t), (0, (a + b) / 2, PLATE_Z - t), "orange"))
        sorter = scene.add_compound(parts, (sx, sy, TABLE_TOP))
        self.add_object("shape_sorter", "shape sorter", sorter, color="yellow",
                        size=(2 * HALF_X, 2 * HALF_Y, PLATE_Z), role="target")
        # In front of the sorter (x < 0.43), so open fingers never touch it.
        xy = sample_positions(rng, 3, (0.32, 0.43), (-0.25, 0.25), 0.1)
        for shape, p in zip(SHAPES, xy, strict=True):
            kind, size, color, _ = SHAPES[shape]
            q = scene.p.getQuaternionFromEuler((0, 0, rng.uniform(-0.6, 0.6)))
            if kind == "box":
                body = scene.add_box(size, (*p, TABLE_TOP + size[2]), q, color=color, mass=0.05)
                dims = tuple(2 * s for s in size)
            else:
                body = scene.add_cylinder(size[0], size[1], (*p, TABLE_TOP + size[1] / 2), q, color=color, mass=0.05)
                dims = (2 * size[0], 2 * size[0], size[1])
            self.add_object(shape, shape, body, color=color, size=dims,
                            role="target" if shape == self.params["shape"] else "distractor")

    def goal(self) -> str:
        """E.g. 'put the cube in the shape sorter'."""
        return f"put the {self.params['shape']} in the shape sorter"

    def expert(self) -> Iterator[Waypoint]:
        """Pick the shape, turn it to the hole's orientation, lower it through, let go."""
        shape = self.params["shape"]
        pos, orn = self.pose(shape)
        obj_yaw = yaw_of(orn)
        if shape == "cuboid":  # fingers across the short side
            yaw = grasp_yaw(obj_yaw + np.pi / 2, np.pi)
        else:
            # Fingers (and the hand's long side) along y, away from the sorter behind the shapes.
            base = obj_yaw if shape == "cube" else 0.0
            yaw = base + np.pi / 2 * np.round((-np.pi / 2 - base) / (np.pi / 2))
        yield from self.pick(shape, pos, yaw, float(pos[2]) + 0.005, lift_z=0.28)
        sorter, _ = self.pose("shape_sorter")
        # Let go with the shape's bottom just inside the hole: the closed fingers are wider
        # than the hole, the shape then drops through.
        hole = np.array([sorter[0], sorter[1] + HOLE_Y[shape], PLATE_Z + 0.012])
        yield from self.carry(shape, shape, "shape sorter", hole, yaw=None, above=0.1, preposition="into")

    def carry(self, obj_name, label, dest, object_target, yaw=None, above=0.1, preposition="onto"):
        """``Task.carry`` with the hand turned so the shape lines up with its hole (the holes'
        sides run along x and y; the cuboid's long side must lie along x)."""
        from envs.tasks.base import finger_yaw

        _, orn = self.pose(obj_name)
        now = yaw_of(orn)
        step = np.pi if obj_name == "cuboid" else np.pi / 2
        turn = np.round(now / step) * step - now
        hand_yaw = finger_yaw(self.scene.ee_pose()[3:]) + turn
        obj_pos, _ = self.pose(obj_name)
        ee = self.scene.ee_pose()[:3]
        off = ee - obj_pos
        c, s = np.cos(turn), np.sin(turn)
        off = np.array([c * off[0] - s * off[1], s * off[0] + c * off[1], off[2]])
        target = np.asarray(object_target) + off
        return self.place(label, dest, target, hand_yaw, float(target[2]), above, preposition)

    def success(self) -> bool:
        """The named shape is inside the sorter box, released."""
        if self.scene.held is not None:
            return False
        pos, _ = self.pose(self.params["shape"])
        sorter, _ = self.pose("shape_sorter")
        d = pos - sorter
        return bool(abs(d[0]) < HALF_X and abs(d[1]) < HALF_Y and pos[2] < PLATE_Z - 0.03)
