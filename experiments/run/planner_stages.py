"""The planner's stages on top of the stage graph: decompositions of the validation demos, the
base planner, its LoRA finetune, and the oracle's plans.

decomposition of the M validation demos -> planner base (pretraining tasks) -> planner finetune
(per decomposer, encoder, M, seed).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from experiments.cache.store import read_json, spec_key
from experiments.config.instantiate import instantiate_component
from experiments.run import components as comp
from experiments.run.graph import Run, each_free_first, finetunes, with_segments
from experiments.run.logs import progress
from rdd.atomic import write_json_atomic
from rdd.metrics import miou


def decompositions(run: Run, tasks: list[str]) -> tuple[list[dict[str, Any]], str]:
    """Decompose and label the M validation demos of each task; rows + key."""
    parts = {**run.runtime_key_parts("decomposer"), **run.runtime_key_parts("labeler")}
    found = each_free_first(tasks, lambda task, wait: _task_decompositions(run, task, parts, wait))
    rows: list[dict[str, Any]] = []
    keys = []
    for task in tasks:
        path, key = found[task]
        keys.append(key)
        rows += read_json(path / "decompositions.json")
    return rows, spec_key({"parts": keys})


def _task_decompositions(run: Run, task: str, parts: dict[str, Any], wait: bool) -> tuple[Path, str] | None:
    """The decompositions stage of one task's validation demos (None: another job's, not waited for)."""
    m, first = run.val_window()
    labelled = run.expert_labels(task, "val", m, first, wait=wait)
    if labelled is None:
        return None
    episodes, expert_key = labelled
    spec = {"demos": expert_key, **parts}

    def build(tmp: Path) -> None:
        decomposer = instantiate_component(run.component("decomposer"), "decomposer", run.runtime("decomposer"))
        labeler = run.labeler()
        out = []
        for ep in progress(episodes, desc=f"decompose {task}", unit="demo"):
            gt = ep.segments
            t0 = time.perf_counter()
            dec = decomposer.decompose(ep)
            seconds = time.perf_counter() - t0
            segs = [tuple(int(v) for v in s) for s in dec.segments]
            out.append({
                "episode": ep.name, "task": ep.task, "num_frames": ep.num_frames,
                "segments": [list(s) for s in segs],
                "instructions": [labeler.label(ep, s) for s in segs],
                "expert_segments": [list(s) for s in gt],
                "miou": float(miou(list(segs), list(gt))),
                "novelty": None if dec.novelty is None else float(dec.novelty),
                "seconds": seconds,
            })
        write_json_atomic(tmp / "decompositions.json", out)

    return run.cache.get_or_build("decompositions", spec, build, wait=wait)


def base_planner_dir(run: Run, planner: Any = None) -> tuple[Path, str]:
    """The base planner pretrained on the pretraining tasks' expert demos (the w/o-finetune one);
    ``planner``: another learned planner than the run's (its describer)."""
    planner = planner or run.learned_planner()
    eps, data_key = run.labelled_set(
        run.pretrain_tasks, "train", int(run.cfg.data.pretrain_episodes_per_task))
    # The tokenizer also covers the evaluation tasks' goals and labeler vocabulary (the paper's
    # planner is a pretrained VLM that already knows the words); no evaluation demo is trained on,
    # only their slot words (colours, drawers, shapes) join the finetune's slot swapping.
    vocab_eps, vocab_key = run.labelled_set(
        run.eval_tasks, "train", int(run.cfg.data.train_episodes_per_task))
    corpus = sorted({s for e in eps + vocab_eps for s in e.instructions}
                    | {e.goal for e in eps + vocab_eps})
    spec = {"planner": planner.base_spec(), "data": data_key, "vocabulary": vocab_key}
    return run.cache.get_or_build(
        "planner_base", spec,
        lambda tmp, saves: comp.pretrain_planner(planner, eps, corpus, tmp, vocab_eps, saves),
        uses=run.node("planner"), resumable=True)


def describer_base_dir(run: Run) -> tuple[Path, str] | None:
    """The base that describes scenes for the run's planner (``planner.describer``), or None."""
    describer = run.learned_planner().describer()
    return None if describer is None else base_planner_dir(run, describer)


def planner_stage(run: Run) -> tuple[Path, Path | None, str, dict[str, Any]]:
    """The planner for this run: the base, or the base LoRA-finetuned on the decomposed demos.

    Returns (base stage dir, finetune stage dir or None, planner key, info); with a describer,
    info holds its base's key ("describer") and stage dir ("describer_dir").
    """
    base_dir, base_key = base_planner_dir(run)
    described = describer_base_dir(run)
    info: dict[str, Any] = {"base": base_key}
    if described is not None:
        info["describer_dir"], info["describer"] = described
    if not finetunes(run.cfg):
        key = base_key if described is None else spec_key({"base": base_key, "describer": described[1]})
        return base_dir, None, key, info
    rows, dec_key = decompositions(run, run.eval_tasks)
    info["decompositions"] = rows
    episodes = {e.name: e for t in run.eval_tasks for e in run.episodes(t, "val", *run.val_window())}
    # the validation demos as the decomposer cut them and the labeler named the pieces
    eps = [with_segments(episodes[r["episode"]], r["segments"], r["instructions"]) for r in rows]
    spec = {"planner": run.node("planner"), "base": base_key, "decompositions": dec_key,
            "seed": int(run.cfg.seed), **({} if described is None else {"describer": described[1]})}
    path, key = run.cache.get_or_build(
        "planner_finetune", spec,
        lambda tmp, saves: comp.finetune_planner(run.learned_planner(), base_dir, eps, int(run.cfg.seed), tmp,
                                                 saves, described and described[0]), resumable=True)
    info["finetune"] = key
    return base_dir, path, key, info


def oracle_plans(run: Run, seeds: list[int]) -> tuple[dict[str, dict[int, list[str]]], str, list]:
    """The expert's labelled instructions for each evaluation task and env seed (cached per task).

    Returns (task -> seed -> instructions, key over all tasks, rows with the expert's success).
    """
    plans: dict[str, dict[int, list[str]]] = {}
    keys, rows = [], []
    for task in run.eval_tasks:
        spec = {"env": run.node("env"), "labeler": run.node("train_labeler"), "task": task,
                "seeds": seeds}

        def build(tmp: Path, task=task) -> None:
            labeler = run.train_labeler()
            write_json_atomic(tmp / "plans.json", [
                {"task": task, **comp.expert_plan(run.cfg.env, task, s, labeler)} for s in seeds])

        path, key = run.cache.get_or_build("oracle_plans", spec, build,
                                            code=comp.task_sources(task))
        keys.append(key)
        got = read_json(path / "plans.json")
        rows += got
        plans[task] = {int(r["seed"]): list(r["instructions"]) for r in got}
    return plans, spec_key({"parts": keys}), rows
