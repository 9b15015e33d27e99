"""The oracle planner: it says the expert's own next instruction (the policy's ceiling).

For each evaluation episode the pipeline records the scripted expert on the same task and env seed,
segments it with the keyframe rule the policy is trained on, and labels the segments with the
training labeler (stage ``oracle_plans``). The oracle then hands those instructions out in order,
one per planner query, whatever the camera shows; after the last one it repeats it. Success with it
measures what the low-level policy can do when the planner makes no mistake.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from planner.interface import Planner


class OraclePlanner(Planner):
    """Plays back the expert's labelled sub-task instructions of the episode being evaluated."""

    # No base model and no finetuning: the pipeline skips the planner stages for it.
    learned = False
    view = "front"  # the loop passes an image; the oracle never looks at it

    def __init__(self, plans: Mapping[str, Mapping[int, Sequence[str]]]) -> None:
        self.plans = {str(t): {int(s): list(p) for s, p in per.items()} for t, per in plans.items()}
        self._plan: list[str] | None = None
        self._next = 0

    def reset(self, task: str, seed: int, goal: str) -> None:
        """Start the episode of (``task``, env ``seed``): its expert plan is played from the top."""
        try:
            plan = self.plans[str(task)][int(seed)]
        except KeyError:
            raise KeyError(f"oracle planner: no expert plan for task {task!r} seed {seed}; it has "
                           f"{ {t: sorted(p) for t, p in self.plans.items()} }") from None
        if not plan:
            raise ValueError(f"oracle planner: the expert plan of {task!r} seed {seed} is empty")
        self._plan, self._next = plan, 0

    def next_instruction(self, image: Any, goal: str, previous_instruction: str | None, state: Any = None) -> str:
        """The expert's next instruction (the last one again once the plan is played out)."""
        if self._plan is None:
            raise RuntimeError("oracle planner: call reset(task, seed, goal) before next_instruction")
        text = self._plan[min(self._next, len(self._plan) - 1)]
        self._next += 1
        return text
