"""Scene methods that add static or movable bodies made of boxes, cylinders and spheres."""

from __future__ import annotations

from envs.bullet import bullet_client, pb

COLORS: dict[str, tuple[float, float, float, float]] = {
    "red": (0.85, 0.1, 0.1, 1.0),
    "green": (0.1, 0.7, 0.15, 1.0),
    "blue": (0.1, 0.25, 0.9, 1.0),
    "yellow": (0.95, 0.85, 0.1, 1.0),
    "purple": (0.55, 0.15, 0.7, 1.0),
    "orange": (1.0, 0.5, 0.0, 1.0),
    "cyan": (0.1, 0.8, 0.85, 1.0),
    "white": (0.95, 0.95, 0.95, 1.0),
    "black": (0.1, 0.1, 0.1, 1.0),
    "grey": (0.5, 0.5, 0.5, 1.0),
    "brown": (0.45, 0.25, 0.1, 1.0),
    "wood": (0.6, 0.45, 0.3, 1.0),
    "pink": (0.95, 0.6, 0.65, 1.0),
}


class PrimitiveBuilders:
    """Body builders of :class:`envs.scene.Scene` (a mixin: it works on the scene's client ``p``)."""

    p: bullet_client.BulletClient

    def _rgba(self, color) -> tuple[float, float, float, float]:
        if isinstance(color, str):
            if color not in COLORS:
                raise ValueError(f"unknown colour {color!r}; known: {sorted(COLORS)}")
            return COLORS[color]
        return tuple(color)

    def recolor(self, body: int, link: int, color) -> None:
        """Repaint every visual shape of one link (``-1`` = the base), e.g. a lamp lighting up."""
        self.p.changeVisualShape(body, link, rgbaColor=self._rgba(color))

    def add_box(self, half_extents, position, quaternion=(0, 0, 0, 1), color="grey", mass=0.1,
                friction=1.0) -> int:
        """A box body; mass 0 makes it static."""
        p = self.p
        col = p.createCollisionShape(pb.GEOM_BOX, halfExtents=half_extents)
        vis = p.createVisualShape(pb.GEOM_BOX, halfExtents=half_extents, rgbaColor=self._rgba(color))
        body = p.createMultiBody(mass, col, vis, basePosition=position, baseOrientation=quaternion)
        p.changeDynamics(body, -1, lateralFriction=friction)
        return body

    def add_cylinder(self, radius, height, position, quaternion=(0, 0, 0, 1), color="grey", mass=0.1,
                     friction=1.0) -> int:
        """An upright cylinder body; mass 0 makes it static."""
        p = self.p
        col = p.createCollisionShape(pb.GEOM_CYLINDER, radius=radius, height=height)
        vis = p.createVisualShape(pb.GEOM_CYLINDER, radius=radius, length=height,
                                  rgbaColor=self._rgba(color))
        body = p.createMultiBody(mass, col, vis, basePosition=position, baseOrientation=quaternion)
        p.changeDynamics(body, -1, lateralFriction=friction)
        return body

    def compound_shapes(self, parts):
        """Collision and visual shape ids of a compound made of ``parts``.

        Each part is ``(kind, size, offset, color)`` with kind ``"box"`` (size = half extents)
        or ``"cylinder"`` (size = (radius, height)) or ``"sphere"`` (size = (radius,)).
        """
        p = self.p
        kinds, radii, halfs, lengths, offsets, colors = [], [], [], [], [], []
        for kind, size, offset, _color in parts:
            offsets.append(list(offset))
            if kind == "box":
                kinds.append(pb.GEOM_BOX)
                halfs.append(list(size))
                radii.append(0.0)
                lengths.append(0.0)
            elif kind == "cylinder":
                kinds.append(pb.GEOM_CYLINDER)
                halfs.append([0.0, 0.0, 0.0])
                radii.append(float(size[0]))
                lengths.append(float(size[1]))
            elif kind == "sphere":
                kinds.append(pb.GEOM_SPHERE)
                halfs.append([0.0, 0.0, 0.0])
                radii.append(float(size[0]))
                lengths.append(0.0)
            else:
                raise ValueError(f"unknown compound part kind {kind!r}")
        col = p.createCollisionShapeArray(kinds, radii=radii, halfExtents=halfs, lengths=lengths,
                                          collisionFramePositions=offsets)
        colors = [list(self._rgba(c)) for *_x, c in parts]
        vis = p.createVisualShapeArray(kinds, radii=radii, halfExtents=halfs, lengths=lengths,
                                       rgbaColors=colors, visualFramePositions=offsets)
        return col, vis

    def add_compound(self, parts, position, quaternion=(0, 0, 0, 1), mass=0.0, friction=1.0) -> int:
        """A rigid body made of several primitives (see ``compound_shapes``)."""
        col, vis = self.compound_shapes(parts)
        body = self.p.createMultiBody(mass, col, vis, basePosition=position, baseOrientation=quaternion)
        self.p.changeDynamics(body, -1, lateralFriction=friction)
        return body

    def add_articulated(self, base_parts, position, links, quaternion=(0, 0, 0, 1)) -> int:
        """A static compound base with movable links.

        ``links`` holds dicts with ``parts`` (see ``compound_shapes``), ``parent`` (0 = base,
        i = i-th link, 1-based as pybullet wants), ``offset`` (link frame in the parent frame),
        ``joint`` (``"prismatic"``, ``"revolute"`` or ``"fixed"``), ``axis``, ``mass``,
        and optional ``limits`` (lower, upper).
        """
        p = self.p
        base_col, base_vis = self.compound_shapes(base_parts)
        kinds = {"prismatic": pb.JOINT_PRISMATIC, "revolute": pb.JOINT_REVOLUTE, "fixed": pb.JOINT_FIXED}
        cols, viss = [], []
        for link in links:
            c, v = self.compound_shapes(link["parts"])
            cols.append(c)
            viss.append(v)
        body = p.createMultiBody(
            0.0, base_col, base_vis, basePosition=position, baseOrientation=quaternion,
            linkMasses=[float(link.get("mass", 0.2)) for link in links],
            linkCollisionShapeIndices=cols, linkVisualShapeIndices=viss,
            linkPositions=[list(link["offset"]) for link in links],
            linkOrientations=[[0, 0, 0, 1]] * len(links),
            linkInertialFramePositions=[[0, 0, 0]] * len(links),
            linkInertialFrameOrientations=[[0, 0, 0, 1]] * len(links),
            linkParentIndices=[int(link["parent"]) for link in links],
            linkJointTypes=[kinds[link["joint"]] for link in links],
            linkJointAxis=[list(link.get("axis", (0, 0, 1))) for link in links],
        )
        for j, link in enumerate(links):
            if "limits" in link:
                lo, hi = link["limits"]
                p.changeDynamics(body, j, jointLowerLimit=lo, jointUpperLimit=hi, jointLimitForce=500)
            p.changeDynamics(body, j, lateralFriction=1.0)
        return body
