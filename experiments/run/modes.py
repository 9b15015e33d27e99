"""What a run does once its config is checked: decompose only, the closed loop, or score the planner."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from experiments.cache.store import read_json
from experiments.config.instantiate import instantiate_component
from experiments.report.result_blocks import decomposition_block, planner_eval_block
from experiments.report.results import average_success, per_task_success
from experiments.run import components as comp
from experiments.run import planner_stages
from experiments.run.graph import Run, finetunes
from rdd.atomic import write_json_atomic


def decompose_only(run: Run, results: dict[str, Any]) -> None:
    """Decompose the validation demos and score them against the expert (mode=decompose)."""
    if not finetunes(run.cfg):
        raise ValueError("mode=decompose needs a decomposer (decomposer=none decomposes nothing)")
    rows, _ = planner_stages.decompositions(run, run.eval_tasks)
    results["tasks"] = run.eval_tasks
    results["decomposition"] = decomposition_block(rows)


def hierarchical(run: Run, results: dict[str, Any]) -> None:
    """The closed loop: planner -> instruction -> policy -> keyframe, per task and env seed."""
    from experiments.run.evaluation import evaluate

    # While another job of the sweep trains the policy, this one builds its planner meanwhile.
    policy = run.policy_stage(wait=False)
    seeds = [comp.test_seed(i) for i in run.evaluation_seeds(int(run.cfg.eval.episodes_per_task))]
    if run.planner_learned():
        base_dir, adapter_dir, planner_key, info = planner_stages.planner_stage(run)
        if "decompositions" in info:
            results["decomposition"] = decomposition_block(info["decompositions"])
        view = run.learned_planner().view

        def make_planner() -> Any:
            planner = run.learned_planner()
            return comp.load_planner(planner, base_dir, adapter_dir,
                                     describer=comp.load_describer(planner, info.get("describer_dir")))
    else:
        plans, planner_key, plan_rows = planner_stages.oracle_plans(run, seeds)
        results["oracle"] = {"expert_success": {
            t: float(np.mean([r["expert_success"] for r in plan_rows if r["task"] == t]))
            for t in run.eval_tasks}}
        view = str(getattr(run.component("planner").target, "view", "front"))

        def make_planner() -> Any:
            return instantiate_component(run.component("planner"), "planner", plans=plans)
    policy_dir, policy_key = policy or run.policy_stage()
    loaded: dict[str, Any] = {}

    def models() -> tuple[Any, Any]:
        # Loaded on the first uncached task only: a finished config reruns without loading them.
        if not loaded:
            loaded["policy"] = comp.load_policy(run.cfg.policy, policy_dir, run.text_cache())
            loaded["planner"] = make_planner()
        return loaded["planner"], loaded["policy"]

    planner_node = run.node("planner")  # its code joins the key: the oracle has no stage key of its own
    episodes: list[dict[str, Any]] = []
    for task in run.eval_tasks:
        spec = {"planner": planner_key, "policy": policy_key, "env": run.node("env"), "task": task,
                "seeds": seeds, "max_steps": int(run.cfg.eval.max_steps)}

        def build(tmp: Path, task=task) -> None:
            planner, policy = models()
            rows = evaluate(run.cfg.env, task, seeds, planner, policy, int(run.cfg.eval.max_steps),
                            view=view)
            write_json_atomic(tmp / "episodes.json", [r.to_dict() for r in rows])

        path, _ = run.cache.get_or_build("evaluation", spec, build, code=comp.task_sources(task),
                                         uses=planner_node)
        episodes += read_json(path / "episodes.json")
    per_task = per_task_success(episodes)
    results.update(
        tasks=run.eval_tasks,
        evaluation_seeds={"split": "test", "env_seeds": seeds},
        episodes=episodes,
        per_task=per_task,
        average_success=average_success(per_task),
        planner=planner_key,
        policy=policy_key,
    )


def planner_eval(run: Run, results: dict[str, Any]) -> None:
    """Exact match of the next instruction at the held-out test episodes' segment starts.

    Base and finetuned planner are scored on the same examples: the expert-segmented, labelled
    test-split episodes of each evaluation task, queried as in the closed loop (image, goal,
    previous instruction), one stage per task.
    """
    if not run.planner_learned():
        raise ValueError("mode=planner_eval scores a trained planner; planner=oracle has nothing to score")
    base_dir, adapter_dir, planner_key, info = planner_stages.planner_stage(run)
    if "decompositions" in info:
        results["decomposition"] = decomposition_block(info["decompositions"])
    n = int(run.cfg.planner_eval.episodes_per_task)
    describes = bool(run.cfg.planner.get("describe_scene", False))
    loaded: dict[str, Any] = {}
    describer: dict[str, Any] = {}

    def planners() -> dict[str, Any]:
        if not loaded:
            planner = run.learned_planner()
            describer["model"] = comp.load_describer(planner, info.get("describer_dir"))
            loaded["base"] = comp.load_planner(planner, base_dir, None, describer=describer["model"])
            if adapter_dir is not None:
                # one base describes the scenes for both (same model, same greedy captions)
                loaded["finetuned"] = comp.load_planner(planner, base_dir, adapter_dir,
                                                        describer=describer["model"] or loaded["base"])
        return loaded

    rows: list[dict[str, Any]] = []
    for task in run.eval_tasks:
        eps, test_key = run.expert_labels(task, "test", n)
        # rows: 2 since each row carries its goal (image-dependent boundaries are found from it)
        spec = {"planner": planner_key, "base": info["base"], "test": test_key, "rows": 2,
                **({"scenes": 2} if describes else {}),
                **({"describer": info["describer"]} if "describer" in info else {})}

        def build(tmp: Path, eps=eps) -> None:
            examples = run.learned_planner().examples(eps)
            out = [{"task": e.task, "episode": e.episode, "frame": int(e.frame), "goal": e.goal,
                    "previous": e.previous_instruction, "target": e.target} for e in examples]
            for name, planner in planners().items():
                preds, hits = planner.hits(examples)
                for row, p, h in zip(out, preds, hits, strict=True):
                    row[name] = p
                    row[f"{name}_hit"] = bool(h)
            if describes:  # what the planners saw (captioned once, above) beside the simulator's truth
                from planner.captions import with_true_scenes
                from planner.prompts import clean_output

                said = (describer["model"] or planners()["base"]).describe([e.image for e in examples])
                true = [clean_output(e.scene) for e in with_true_scenes(examples, eps)]  # as answers are read
                for row, s, t in zip(out, said, true, strict=True):
                    row.update(scene=s, scene_true=t)
            write_json_atomic(tmp / "boundaries.json", out)

        path, _ = run.cache.get_or_build("planner_eval", spec, build)
        rows += read_json(path / "boundaries.json")
    results.update(tasks=run.eval_tasks, planner=planner_key,
                   planner_eval=planner_eval_block(rows, run.eval_tasks, finetuned=adapter_dir is not None))
