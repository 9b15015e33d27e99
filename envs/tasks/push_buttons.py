"""push_buttons: push the named coloured buttons in the stated order."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from envs.poses import top_down_quat
from envs.scene import TABLE_TOP, Scene
from envs.tasks.base import Task, Waypoint, grasp_yaw, sample_positions
from rdd.registry import register

COLORS = ("red", "green", "blue", "yellow", "purple", "cyan")
BASE_H = 0.02
CAP_R, CAP_H = 0.022, 0.02
TRAVEL = 0.015
# depression (m) that counts as a press and lights the lamp: half the travel, as envs.record
# documents, so the lamp can be read back from the record's button states
PRESSED = TRAVEL / 2
UNLIT, LIT = "grey", "white"  # a button's base lights up once it has been pressed, as RLBench's
FINGERTIP = 0.011  # closed fingertips reach this far below the grasp point


@register("task", "push_buttons")
class PushButtons(Task):
    """Three buttons; push 1, 2 or 3 of them in the order the goal gives."""

    name = "push_buttons"
    order = 5
    description = "push the named buttons in order"

    def variations(self):
        """How many buttons to push (their colours and order come from the seed)."""
        return [{"count": n} for n in (1, 2, 3)]

    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Three spring-loaded buttons with distinct colours on grey bases that light up when pressed."""
        colors = [COLORS[i] for i in rng.choice(len(COLORS), size=3, replace=False)]
        xy = sample_positions(rng, 3, (0.38, 0.6), (-0.22, 0.22), 0.12)
        self.sequence = [colors[i] for i in rng.permutation(3)[: self.params["count"]]]
        self.buttons = {}
        for c, p in zip(colors, xy, strict=True):
            base = [("box", (0.035, 0.035, BASE_H / 2), (0, 0, BASE_H / 2), UNLIT)]
            cap = [("cylinder", (CAP_R, CAP_H), (0, 0, 0), c)]
            body = scene.add_articulated(base, (*p, TABLE_TOP), [{
                "parts": cap, "parent": 0, "offset": (0, 0, BASE_H + CAP_H / 2), "joint": "prismatic",
                "axis": (0, 0, 1), "mass": 0.02, "limits": (-TRAVEL, 0.0)}])
            # A weak position servo is the return spring.
            scene.p.setJointMotorControl2(body, 0, 2, targetPosition=0.0, force=4.0)  # 2 = POSITION_CONTROL
            self.add_object(f"{c}_button", "button", body, 0, color=c, size=(2 * CAP_R, 2 * CAP_R, CAP_H),
                            role="target" if c in self.sequence else "distractor")
            self.add_articulation(f"{c}_button", "button", body, 0, 0.0, TRAVEL, sign=-1.0)
            self.buttons[c] = body
        self.pressed: list[str] = []
        scene.step_hooks.append(self._watch)

    def _watch(self) -> None:
        """Latch the order in which buttons are first pressed and light their bases: the buttons
        spring back, so only the lamp shows which ones are done (RLBench's top plates turn green)."""
        for c in self.buttons:
            if c not in self.pressed and self.art_state(f"{c}_button") >= PRESSED:
                self.pressed.append(c)
                self.scene.recolor(self.buttons[c], -1, LIT)

    def goal(self) -> str:
        """E.g. 'push the red button, then the blue button'."""
        parts = [f"the {c} button" for c in self.sequence]
        return "push " + ", then ".join(parts)

    def graspable(self) -> list[tuple[int, int]]:
        """Nothing is grasped in this task."""
        return []

    def expert(self) -> Iterator[Waypoint]:
        """For each button: hover above it (closing the gripper first time), press, lift."""
        q = top_down_quat(grasp_yaw(0.0, np.pi))
        for c in self.sequence:
            cap, _ = self.pose(f"{c}_button")
            top = cap[2] + CAP_H / 2
            hover = np.array([cap[0], cap[1], top + FINGERTIP + 0.06])
            press = np.array([cap[0], cap[1], top + FINGERTIP - 0.012])
            yield Waypoint(hover, q, False, f"move above the {c} button")
            yield Waypoint(press, q, False, f"push the {c} button")
            yield Waypoint(hover.copy(), q, False, f"release the {c} button")

    def success(self) -> bool:
        """Exactly the named buttons were pressed, in the named order."""
        return self.pressed == self.sequence
