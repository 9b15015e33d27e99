"""The high-level planner's interface: ``reset(task, seed, goal)`` then ``next_instruction(...)``.

The closed loop (``experiments.run.evaluation``) asks it, at every step, for the sub-task
instruction the low-level policy (:class:`policy.interface.Policy`) carries out next.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar


class Planner(ABC):
    """Says the next sub-task instruction from what the robot sees and the task's goal."""

    view: ClassVar[str] = "front"  # the camera whose image the loop passes
    learned: ClassVar[bool] = True  # a trained model (its base and finetune are pipeline stages)

    def reset(self, task: str, seed: int, goal: str) -> None:  # noqa: B027 - optional hook
        """Start a new episode of ``task`` (env ``seed``) with language goal ``goal``."""

    @abstractmethod
    def next_instruction(self, image: Any, goal: str, previous_instruction: str | None, state: Any = None) -> str:
        """The next sub-task instruction for the camera ``image``, the goal, the previous instruction
        and the robot's proprioceptive ``state`` (a mapping with ``ee_pose`` and ``gripper_open``),
        as the paper's planner pi(l_t | s_t, o_t, l_{t-1}, L) reads them."""
