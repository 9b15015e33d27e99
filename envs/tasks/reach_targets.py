"""reach_targets: reach the named coloured targets in the stated order (planner pretraining task).

RLBench's reach_target with a list of targets instead of one. It is here for the planner's base:
a pretrained VLM already follows an ordered goal ("the red one, then the blue one"), the tiny base
trained on this CPU learns it from this task, never from an evaluation task.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.scene import TABLE_TOP, Scene, top_down_quat
from envs.tasks.base import Task, Waypoint, grasp_yaw, sample_positions

COLORS = ("red", "green", "blue", "yellow", "purple", "cyan")
PAD_R, PAD_H = 0.03, 0.01
HOVER = 0.05  # the grasp point stops this far above a target's top
VISIT_R = 0.025  # a target counts as reached with the grasp point this near its axis ...
VISIT_H = 0.08  # ... and at most this high above its top


class ReachTargets(Task):
    """Four flat targets; reach 2, 3 or 4 of them in the order the goal gives."""

    name = "reach_targets"
    pretraining = True
    description = "reach the named targets in order"

    def variations(self):
        """How many targets to reach (their colours and order come from the seed)."""
        return [{"count": n} for n in (2, 3, 4)]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Four static discs of distinct colours on the table."""
        colors = [COLORS[i] for i in rng.choice(len(COLORS), size=4, replace=False)]
        start = scene.ee_pose()[:2]
        for _ in range(100):  # a layout whose straight route passes over no other target
            xy = sample_positions(rng, 4, (0.36, 0.62), (-0.25, 0.25), 0.13)
            order = rng.permutation(4)[: self.params["count"]]
            if _clear_route([start, *(xy[i] for i in order)], xy):
                break
        else:
            raise RuntimeError("reach_targets: no layout with a clear route in 100 draws")
        self.sequence = [colors[i] for i in order]
        self.centres = {}
        for c, p in zip(colors, xy, strict=True):
            body = scene.add_cylinder(PAD_R, PAD_H, (*p, TABLE_TOP + PAD_H / 2), color=c, mass=0.0)
            self.add_object(f"{c}_target", "target", body, color=c, size=(2 * PAD_R, 2 * PAD_R, PAD_H),
                            role="target" if c in self.sequence else "distractor")
            self.centres[c] = np.array([p[0], p[1], TABLE_TOP + PAD_H])
        self.reached: list[str] = []
        scene.step_hooks.append(self._watch)

    def _watch(self) -> None:
        """Latch the order in which targets are first reached."""
        ee = self.scene.ee_pose()[:3]
        for c, top in self.centres.items():
            if (c not in self.reached and np.linalg.norm(ee[:2] - top[:2]) < VISIT_R
                    and 0.0 <= ee[2] - top[2] <= VISIT_H):
                self.reached.append(c)

    def goal(self) -> str:
        """E.g. 'reach the red target, then the blue target'."""
        return "reach " + ", then ".join(f"the {c} target" for c in self.sequence)

    def graspable(self) -> list[tuple[int, int]]:
        """Nothing is grasped in this task."""
        return []

    def expert(self) -> Iterator[Waypoint]:
        """Stop above each named target in turn, gripper open."""
        q = top_down_quat(grasp_yaw(0.0, np.pi))
        for c in self.sequence:
            yield Waypoint(self.centres[c] + np.array([0.0, 0.0, HOVER]), q, True, f"reach for the {c} target")

    def success(self) -> bool:
        """The named targets were reached in the named order (others passed over do not count)."""
        return [c for c in self.reached if c in self.sequence] == self.sequence


def _clear_route(stops, centres, clearance: float = 0.06) -> bool:
    """No centre other than a leg's own ends lies within ``clearance`` of that straight leg."""
    for a, b in zip(stops[:-1], stops[1:], strict=True):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        d = b - a
        for c in centres:
            c = np.asarray(c, dtype=float)
            if np.linalg.norm(c - a) < 1e-9 or np.linalg.norm(c - b) < 1e-9:
                continue
            t = np.clip(np.dot(c - a, d) / max(np.dot(d, d), 1e-12), 0.0, 1.0)
            if np.linalg.norm(a + t * d - c) < clearance:
                return False
    return True
