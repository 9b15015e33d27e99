"""The seeded hierarchical evaluation loop.

For each evaluation episode: reset the env with a test-split seed, then repeat
observation -> planner -> instruction -> policy -> keyframe -> controller -> observation until the
task's success detector fires or the step limit is reached. The planner is queried exactly as it was
trained (image of its view, goal, previous instruction; None at the first step).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from omegaconf import DictConfig

from experiments.report.results import EpisodeResult
from experiments.run import components as comp
from experiments.run.logs import progress
from planner.interface import Planner
from policy.interface import Policy

log = logging.getLogger(__name__)


def run_episode(env: Any, seed: int, planner: Planner, policy: Policy, max_steps: int, view: str) -> EpisodeResult:
    """One closed-loop episode; never raises for a failed motion (the episode just fails)."""
    obs, info = env.reset(seed=int(seed))
    goal = comp.episode_goal(env, info)
    policy.reset(goal)
    planner.reset(task=str(env.task_name), seed=int(seed), goal=goal)
    previous: str | None = None
    instructions: list[str] = []
    failure: str | None = "step limit"
    steps = 0
    success = bool(info.get("success", False))
    while not success and steps < max_steps:
        instruction = planner.next_instruction(comp.observation_image(obs, view), goal, previous,
                                               state={"ee_pose": obs["ee_pose"], "gripper_open": obs["gripper_open"]})
        action = policy.act(comp.policy_observation(env, obs), instruction)
        obs, _reward, terminated, truncated, info = env.step(comp.action_array(action))
        steps += 1
        instructions.append(instruction)
        previous = instruction
        success = bool(info.get("success", False))
        if success:
            failure = None
            break
        if terminated or truncated:
            failure = str(info.get("failure") or ("terminated" if terminated else "truncated"))
            break
        if info.get("motion_failed"):
            failure = f"last motion failed: {info.get('failure')}"  # the loop goes on: replan
    return EpisodeResult(task=str(env.task_name), seed=int(seed), success=success, steps=steps,
                         instructions=instructions, failure=None if success else failure)


def evaluate(env_cfg: DictConfig, task: str, seeds: Sequence[int], planner: Any, policy: Any,
             max_steps: int, view: str = "front") -> list[EpisodeResult]:
    """Evaluate ``task`` on each env seed in ``seeds`` (from the test split's range)."""
    env = comp.make_env(env_cfg, task)
    try:
        out = []
        for seed in progress(seeds, desc=f"evaluate {task}", unit="ep"):
            res = run_episode(env, seed, planner, policy, max_steps, view)
            log.debug("%s seed %d: %s in %d step(s)", task, seed,
                     "success" if res.success else f"failure ({res.failure})", res.steps)
            out.append(res)
        return out
    finally:
        close = getattr(env, "close", None)
        if close is not None:
            close()
