"""One run of the harness: cached stages, then closed-loop evaluation, then ``results.json``.

Stages (each cached under ``paths.cache_dir`` by the config that affects it, see ``stages.py``):
episodes per task and split -> expert segmentation + labels -> policy -> sub-task database (per
encoder; + calibration, for a calibrated decomposer only) -> decomposition of the M validation
demos -> planner base (pretraining tasks) -> planner finetune (per decomposer, encoder, M, seed)
-> evaluation (per planner, policy, evaluation seeds).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from omegaconf import DictConfig, OmegaConf

from experiments import components as comp
from experiments.instantiate import check_call, instantiate_component, runtime_names
from experiments.logs import progress, quiet_libraries, show_progress, stage_lines
from experiments.results import (
    RESULTS_FILE,
    RESULTS_FORMAT,
    average_success,
    method_label,
    per_task_success,
)
from experiments.stages import StageCache, read_json, spec_key, stage_code_key, write_json_atomic
from experiments.validate import target_callable, validate_config
from rdd.data.episode import Episode

log = logging.getLogger(__name__)
T = TypeVar("T")
R = TypeVar("R")


class Unavailable(RuntimeError):
    """A component cannot run on this machine (e.g. an encoder whose weights are absent)."""


def _hydra_info() -> tuple[Path | None, dict[str, Any], list[str], bool, int]:
    """(output dir, group choices, task overrides, is multirun, parallel jobs) from Hydra if active."""
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
    except (ImportError, ValueError):
        return None, {}, [], False, 1
    choices = {k: v for k, v in OmegaConf.to_container(hc.runtime.choices).items()
               if not k.startswith("hydra")}
    multirun = hc.mode == RunMode.MULTIRUN
    n_jobs = int(OmegaConf.select(hc, "launcher.n_jobs", default=1) or 1) if multirun else 1
    return Path(hc.runtime.output_dir), choices, list(hc.overrides.task), multirun, n_jobs


def _set_threads(cfg: DictConfig, n_jobs: int) -> int:
    import torch

    threads = cfg.threads
    if threads is None:
        threads = _default_threads(n_jobs)
    torch.set_num_threads(int(threads))
    return int(threads)


def _default_threads(n_jobs: int) -> int:
    """Torch threads for a job: its share of the CPUs it may use, as its launcher allotted them.

    joblib sweeps split this machine between ``n_jobs``; a Slurm job gets ``SLURM_CPUS_PER_TASK``,
    a Ray task ``OMP_NUM_THREADS`` (Ray sets it to the task's ``num_cpus``); otherwise every CPU in
    the process's affinity mask (a cgroup or ``taskset`` limit), not every core of the node.
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if n_jobs <= 0:  # joblib's n_jobs=-1: one job per core
        return 1
    if n_jobs > 1:
        return max(1, cores // n_jobs)
    for var in ("SLURM_CPUS_PER_TASK", "OMP_NUM_THREADS"):
        value = os.environ.get(var, "")
        if value.isdigit() and int(value) > 0:
            return min(int(value), cores)
    return max(1, cores)


def _hardware() -> dict[str, Any]:
    import torch

    return {
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cuda": bool(torch.cuda.is_available()),
    }


def each_free_first(items: Sequence[T], attempt: Callable[[T, bool], R | None]) -> dict[T, R]:
    """``attempt(item, wait)`` for every item: first without waiting (None when another job holds
    the item's stage), then waiting for the rest one at a time. Concurrent jobs of a cold sweep
    thus split per-task stages between them instead of queueing behind each other."""
    done: dict[T, R] = {}
    pending = list(dict.fromkeys(items))
    while pending:
        for item in pending:
            got = attempt(item, False)
            if got is not None:
                done[item] = got
        if all(item not in done for item in pending):  # every one is another job's now: wait
            done[pending[0]] = attempt(pending[0], True)
        pending = [item for item in pending if item not in done]
    return done


class Run:
    """State shared by the stages of one run."""

    def __init__(self, cfg: DictConfig, out_dir: Path, cache: StageCache):
        self.cfg = cfg
        self.out_dir = out_dir
        self.cache = cache
        self.views = list(cfg.views)
        self._encoder = None
        self._encoder_key: str | None = None
        self._database = None
        self._database_key: str | None = None
        self._episode_cache: dict[str, Any] = {}
        self._episode_keys: dict[str, str] = {}  # episode name -> its stage key
        self._labeler = None
        self._train_labeler = None
        self.env_info = comp.env_info(cfg.env)
        self.eval_tasks = self._eval_tasks()
        self.pretrain_tasks = self._pretrain_tasks()

    # --- configuration pieces that key the stages -------------------------------------------
    def _eval_tasks(self) -> list[str]:
        tasks = list(self.cfg.tasks) if self.cfg.tasks is not None else list(self.env_info.evaluation_tasks)
        known = set(self.env_info.all_tasks)
        unknown = [t for t in tasks if t not in known]
        if unknown:
            raise ValueError(f"tasks: unknown task(s) {unknown}; the env has {sorted(known)}")
        if not tasks:
            raise ValueError("tasks: no evaluation task selected")
        return tasks

    def _pretrain_tasks(self) -> list[str]:
        tasks = self.cfg.data.pretrain_tasks
        tasks = list(self.env_info.pretraining_tasks) if tasks is None else list(tasks)
        overlap = sorted(set(tasks) & set(self.eval_tasks))
        if overlap:
            raise ValueError(f"data.pretrain_tasks {overlap} are also evaluated: the base planner "
                             "must never see an evaluation task")
        unknown = [t for t in tasks if t not in set(self.env_info.all_tasks)]
        if unknown or not tasks:
            raise ValueError(f"data.pretrain_tasks: unknown or no task(s) {unknown or tasks}")
        return tasks

    def node(self, group: str) -> dict[str, Any]:
        """A component's resolved config as a plain dict (part of stage keys)."""
        node = self.cfg.get(group)
        return {} if node is None else OmegaConf.to_container(node, resolve=True)

    # --- runtime objects -----------------------------------------------------------------------
    def encoder(self):
        """The visual encoder (loaded once; missing weights fail here, before any long work)."""
        if self._encoder is None:
            try:
                self._encoder = instantiate_component(self.cfg.encoder, "encoder")
            except (FileNotFoundError, ImportError, OSError) as exc:
                name = str(self.cfg.encoder.get("_target_", "?")).removesuffix(".build").rsplit(".", 1)[-1]
                raise Unavailable(f"encoder {name!r}: {exc}") from exc
            self._encoder_key = spec_key({"encoder": self.node("encoder"),
                                          "weights_id": self._encoder.weights_id})
        return self._encoder

    def encoder_key(self) -> str:
        """Key of the encoder's config and weights."""
        self.encoder()
        assert self._encoder_key is not None
        return self._encoder_key

    def embedding_cache(self):
        """The shared on-disk embedding cache (the runtime object ``cache``)."""
        return comp.embedding_cache(Path(self.cfg.paths.cache_dir) / "embeddings")

    # --- stages ----------------------------------------------------------------------------------
    def demos_key(self, task: str) -> str:
        """Key of ``task``'s demos: the env config, the shared env code and the task's own module."""
        return spec_key({"env": self.node("env"), "code": stage_code_key("demos", comp.task_sources(task))})

    def episodes(self, task: str, split: str, count: int, first: int = 0, wait: bool = True) -> list | None:
        """Successful scripted demos ``first .. first+count-1`` of ``task`` in ``split`` (cached).

        Generation is resumable per episode, so a run asking for 3 demos reuses the 1 an earlier
        run made; each episode's key is its env config, task, split and seed. ``wait=False``:
        None at once when another job is generating this task's demos.
        """
        env_key = self.demos_key(task)
        root = self.cache.root / "demos" / env_key
        with self.cache.lock("demos", f"{env_key}-{task}-{split}", wait=wait) as held:
            if not held:
                return None
            with self.cache.timed("episodes") as timing:
                before = set(root.glob(f"{split}/{task}/*/episode.json"))
                dirs = comp.episodes_for(self.cfg.env, task, split, first + count, root)[first:]
                timing["cached"] = all(d / "episode.json" in before for d in dirs)
        out = []
        for d in dirs:
            key = spec_key({"demos": env_key, "episode": d.name, "split": split})
            if key not in self._episode_cache:
                ep = comp.load_episode(d)
                self._episode_cache[key] = ep
                self._episode_keys[ep.name] = key
            out.append(self._episode_cache[key])
        return out

    def expert_labels(self, task: str, split: str, count: int, first: int = 0,
                      wait: bool = True) -> tuple[list[Episode], str] | None:
        """Episodes carrying expert segments and labeller instructions (copies), and a key over them
        (``wait=False``: None at once while another job generates the demos)."""
        episodes = self.episodes(task, split, count, first, wait=wait)
        if episodes is None:
            return None
        out, keys = [], []
        for ep in episodes:
            spec = {"episode": self._episode_keys[ep.name], "labeler": self.node("train_labeler")}

            def build(tmp: Path, ep=ep) -> None:
                labeler = self.train_labeler()
                segs = comp.expert_segments(ep)
                write_json_atomic(tmp / "labels.json", {
                    "episode": ep.name, "segments": [list(s) for s in segs],
                    "instructions": [labeler.label(ep, tuple(s)) for s in segs]})

            path, key = self.cache.get_or_build("expert_labels", spec, build)
            row = read_json(path / "labels.json")
            out.append(with_segments(ep, row["segments"], row["instructions"]))
            keys.append(key)
        return out, spec_key({"parts": keys})

    def labelled_set(self, tasks: list[str], split: str, count: int) -> tuple[list[Episode], str]:
        """Expert-segmented, labelled episodes of several tasks, and a key over all of them."""
        each_free_first(tasks, lambda task, wait: self.episodes(task, split, count, wait=wait))
        eps, keys = [], []
        for task in tasks:
            e, k = self.expert_labels(task, split, count)
            eps += e
            keys.append(k)
        return eps, spec_key({"parts": keys})

    def policy_stage(self, wait: bool = True) -> tuple[Path, str] | None:
        """The keyframe policy trained on expert-decomposed, labelled training episodes
        (``wait=False``: None at once while another job trains it)."""
        eps, data_key = self.labelled_set(
            self.policy_tasks(), "train", int(self.cfg.data.train_episodes_per_task))
        spec = {"policy": self.node("policy"), "data": data_key}
        return self.cache.get_or_build(
            "policy", spec,
            lambda tmp: comp.train_policy(self.cfg.policy, eps, self.train_labeler(),
                                          self.text_cache(), tmp), wait=wait)

    def labeler(self):
        """The labeller of decomposed demonstrations, shared by every decomposer (built once)."""
        if self._labeler is None:
            self._labeler = instantiate_component(self.cfg.labeler, "labeler",
                                                  self.runtime(self.cfg.labeler, "labeler"))
        return self._labeler

    def train_labeler(self):
        """The labeller of the expert-segmented training set (built once)."""
        if self._train_labeler is None:
            self._train_labeler = instantiate_component(self.cfg.train_labeler, "train_labeler")
        return self._train_labeler

    def text_cache(self) -> Path:
        """Shared cache of instruction embeddings (the policy's sentence encoder)."""
        return Path(self.cfg.paths.cache_dir) / "text"

    def policy_tasks(self) -> list[str]:
        """Tasks the policy learns: every evaluation task of this run."""
        return list(self.eval_tasks)

    def database_tasks(self) -> list[str]:
        """Tasks whose expert sub-tasks fill the database (default: the evaluation tasks)."""
        tasks = self.cfg.data.database_tasks
        if tasks is None:
            return list(self.eval_tasks)
        tasks = list(tasks)
        unknown = [t for t in tasks if t not in set(self.env_info.all_tasks)]
        if unknown or not tasks:
            raise ValueError(f"data.database_tasks: unknown or no task(s) {unknown or tasks}")
        return tasks

    def database(self):
        """The sub-task database of the training episodes under this run's encoder (calibrated
        when the decomposer asks for it: a stage of its own, so other runs never pay for it)."""
        if self._database is None:
            tasks = self.database_tasks()
            # one part per task, so that the concurrent jobs of a cold sweep embed different tasks
            parts = each_free_first(tasks, self._database_part)
            spec = {"parts": [parts[t][1] for t in tasks]}
            path, key = self.cache.get_or_build(
                "database", spec, lambda tmp: comp.merge_databases([parts[t][0] for t in tasks], tmp))
            if self.uses_calibration():
                eps, _ = self.labelled_set(tasks, "train", int(self.cfg.data.train_episodes_per_task))
                path, key = self.cache.get_or_build(
                    "calibration", {"database": key},
                    lambda tmp, plain=path: comp.calibrate_database(
                        plain, eps, self.encoder(), self.views, self.embedding_cache(), tmp))
            self._database = comp.load_database(path)
            self._database_key = key
        return self._database

    def _database_part(self, task: str, wait: bool) -> tuple[Path, str] | None:
        """The sub-task database of one task's training episodes (``wait=False``: None at once
        while another job builds it or generates its demos)."""
        got = self.expert_labels(task, "train", int(self.cfg.data.train_episodes_per_task), wait=wait)
        if got is None:
            return None
        eps, data_key = got
        spec = {"data": data_key, "encoder": self.encoder_key(), "views": self.views}
        return self.cache.get_or_build(
            "database_part", spec,
            lambda tmp: comp.build_database(eps, self.encoder(), self.views, self.embedding_cache(), tmp),
            wait=wait)

    def uses_calibration(self) -> bool:
        """Whether the decomposer takes its options from the database's calibration."""
        node = self.cfg.get("decomposer")
        return bool(node is not None and node.get("use_calibration", False))

    def runtime(self, node: DictConfig, group: str) -> dict[str, Any]:
        """The runtime objects the component of ``node`` takes, each under its one name."""
        build = {"database": self.database, "encoder": self.encoder, "cache": self.embedding_cache}
        return {name: build[name]() for name in runtime_names(node, group)}

    def planner_learned(self) -> bool:
        """Whether the planner is a trained model (base + LoRA stages) rather than the oracle."""
        return bool(getattr(target_callable(self.cfg.planner, "planner"), "learned", True))

    def decomposes(self) -> bool:
        """Whether this run decomposes the validation demos (to finetune a learned planner)."""
        return finetunes(self.cfg) and self.planner_learned()

    def runtime_key_parts(self, group: str) -> dict[str, Any]:
        """What a component's output depends on besides its config: the runtime objects it takes."""
        node = self.cfg.get(group)
        parts: dict[str, Any] = {group: self.node(group)}
        if node is None or not node.get("_target_"):
            return parts
        takes = runtime_names(node, group)
        if "encoder" in takes or "database" in takes:
            parts["encoder"] = self.encoder_key()
        if "database" in takes:
            self.database()
            parts["database"] = self._database_key
        return parts

    def val_window(self) -> tuple[int, int]:
        """(M, first): the validation demos ``first .. first+M-1`` the planner is finetuned on."""
        m, first = int(self.cfg.data.val_episodes_per_task), int(self.cfg.data.val_first_episode)
        if first < 0:
            raise ValueError(f"data.val_first_episode must be >= 0, got {first}")
        return m, first

    def decompositions(self, tasks: list[str]) -> tuple[list[dict[str, Any]], str]:
        """Decompose and label the M validation demos of each task; rows + key."""
        parts = {**self.runtime_key_parts("decomposer"), **self.runtime_key_parts("labeler")}
        found = each_free_first(tasks, lambda task, wait: self._task_decompositions(task, parts, wait))
        rows: list[dict[str, Any]] = []
        keys = []
        for task in tasks:
            path, key = found[task]
            keys.append(key)
            rows += read_json(path / "decompositions.json")
        return rows, spec_key({"parts": keys})

    def _task_decompositions(self, task: str, parts: dict[str, Any], wait: bool) -> tuple[Path, str] | None:
        """The decompositions stage of one task's validation demos (None: another job's, not waited for)."""
        m, first = self.val_window()
        labelled = self.expert_labels(task, "val", m, first, wait=wait)
        if labelled is None:
            return None
        episodes, expert_key = labelled
        spec = {"demos": expert_key, **parts}

        def build(tmp: Path) -> None:
            decomposer = instantiate_component(self.cfg.decomposer, "decomposer",
                                               self.runtime(self.cfg.decomposer, "decomposer"))
            labeler = self.labeler()
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
                    "miou": float(comp.miou(segs, gt)),
                    "novelty": None if dec.novelty is None else float(dec.novelty),
                    "seconds": seconds,
                })
            write_json_atomic(tmp / "decompositions.json", out)

        return self.cache.get_or_build("decompositions", spec, build, wait=wait)

    def base_planner_dir(self) -> tuple[Path, str]:
        """The base planner pretrained on the pretraining tasks' expert demos (the w/o-finetune one)."""
        eps, data_key = self.labelled_set(
            self.pretrain_tasks, "train", int(self.cfg.data.pretrain_episodes_per_task))
        # The tokenizer also covers the evaluation tasks' goals and labeller vocabulary (the paper's
        # planner is a pretrained VLM that already knows the words); no evaluation demo is trained on,
        # only their slot words (colours, drawers, shapes) join the finetune's slot swapping.
        vocab_eps, vocab_key = self.labelled_set(
            self.eval_tasks, "train", int(self.cfg.data.train_episodes_per_task))
        corpus = sorted({s for e in eps + vocab_eps for s in e.instructions}
                        | {e.goal for e in eps + vocab_eps})
        spec = {"planner": comp.planner_base_spec(self.cfg.planner), "data": data_key,
                "vocabulary": vocab_key}
        return self.cache.get_or_build(
            "planner_base", spec,
            lambda tmp: comp.pretrain_planner(self.cfg.planner, eps, corpus, tmp, vocab_eps))

    def planner_stage(self) -> tuple[Path, Path | None, str, dict[str, Any]]:
        """The planner for this run: the base, or the base LoRA-finetuned on the decomposed demos.

        Returns (base stage dir, finetune stage dir or None, planner key, info).
        """
        base_dir, base_key = self.base_planner_dir()
        info: dict[str, Any] = {"base": base_key}
        if not finetunes(self.cfg):
            return base_dir, None, base_key, info
        rows, dec_key = self.decompositions(self.eval_tasks)
        info["decompositions"] = rows
        episodes = {e.name: e for t in self.eval_tasks for e in self.episodes(t, "val", *self.val_window())}
        # the validation demos as the decomposer cut them and the labeller named the pieces
        eps = [with_segments(episodes[r["episode"]], r["segments"], r["instructions"]) for r in rows]
        spec = {"planner": self.node("planner"), "base": base_key, "decompositions": dec_key,
                "seed": int(self.cfg.seed)}
        path, key = self.cache.get_or_build(
            "planner_finetune", spec,
            lambda tmp: comp.finetune_planner(self.cfg.planner, base_dir, eps, int(self.cfg.seed), tmp))
        info["finetune"] = key
        return base_dir, path, key, info

    def oracle_plans(self, seeds: list[int]) -> tuple[dict[str, dict[int, list[str]]], str, list]:
        """The expert's labelled instructions for each evaluation task and env seed (cached per task).

        Returns (task -> seed -> instructions, key over all tasks, rows with the expert's success).
        """
        plans: dict[str, dict[int, list[str]]] = {}
        keys, rows = [], []
        for task in self.eval_tasks:
            spec = {"env": self.node("env"), "labeler": self.node("train_labeler"), "task": task,
                    "seeds": seeds}

            def build(tmp: Path, task=task) -> None:
                labeler = self.train_labeler()
                write_json_atomic(tmp / "plans.json", [
                    {"task": task, **comp.expert_plan(self.cfg.env, task, s, labeler)} for s in seeds])

            path, key = self.cache.get_or_build("oracle_plans", spec, build,
                                                code=comp.task_sources(task))
            keys.append(key)
            got = read_json(path / "plans.json")
            rows += got
            plans[task] = {int(r["seed"]): list(r["instructions"]) for r in got}
        return plans, spec_key({"parts": keys}), rows

    def evaluation_seeds(self, n: int) -> list[int]:
        """Test-split seed indices of this run's evaluation episodes."""
        base = int(self.cfg.seed) * int(self.cfg.eval.seed_stride)
        if n > int(self.cfg.eval.seed_stride):
            raise ValueError(f"eval.episodes_per_task={n} exceeds eval.seed_stride")
        return [base + i for i in range(n)]


def with_segments(episode: Episode, segments: list, instructions: list[str]) -> Episode:
    """A copy of ``episode`` carrying ``segments`` and their ``instructions`` (the cached one stays as is)."""
    return dataclasses.replace(episode, segments=[tuple(int(v) for v in s) for s in segments],
                               instructions=list(instructions), meta=dict(episode.meta))


def finetunes(cfg: DictConfig) -> bool:
    """Whether the planner is finetuned: decomposer `none` (no _target_) keeps the base planner."""
    node = cfg.get("decomposer")
    return node is not None and bool(node.get("_target_"))


def preflight(run: Run) -> None:
    """Cheap checks before any long work: the runtime objects needed (keys and types: validate_config)."""
    if not run.decomposes():
        return
    takes: set[str] = set()
    for group in ("decomposer", "labeler"):
        node = run.cfg[group]
        names = runtime_names(node, group)
        check_call(node, group, names)  # a parameter nothing fills fails now, not after the demos
        takes |= set(names)
    if takes & {"encoder", "database"}:
        run.encoder()  # a missing checkpoint fails here, at once


def run(cfg: DictConfig) -> dict[str, Any]:
    """Run one configuration end to end; writes results.json and returns its summary."""
    validate_config(cfg)  # unknown or mistyped keys fail here, before anything is written
    out_dir, choices, overrides, multirun, n_jobs = _hydra_info()
    if out_dir is None:
        out_dir = Path(OmegaConf.select(cfg, "output_dir", default=None) or "outputs/run")
    out_dir.mkdir(parents=True, exist_ok=True)
    quiet_libraries()
    show_progress(not multirun or n_jobs == 1)  # parallel jobs' bars would interleave
    threads = _set_threads(cfg, n_jobs)
    mode = str(OmegaConf.select(cfg, "mode")).split(".")[-1]
    resolved = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
    write_json_atomic(out_dir / "config_resolved.json", resolved)
    results: dict[str, Any] = {
        "format": RESULTS_FORMAT,
        "status": "ok",
        "mode": mode,
        "seed": int(cfg.seed),
        "choices": choices,
        "overrides": overrides,
        "label": method_label(overrides, choices),
        "hardware": {**_hardware(), "torch_threads": threads, "parallel_jobs": n_jobs},
        "config": resolved,
    }
    from experiments.tracking import Tracker

    tracker = Tracker(cfg.wandb, resolved, out_dir,
                      name=f"{choices.get('experiment', 'run')}-{results['label']}-s{cfg.seed}")
    t_start = time.perf_counter()
    cache = StageCache(Path(cfg.paths.cache_dir))
    try:
        if mode == "speed":
            from experiments.speed import measure_speed

            with cache.timed("speed"):
                results["speed"] = measure_speed(cfg)
        else:
            run_obj = Run(cfg, out_dir, cache)
            try:
                preflight(run_obj)
            except Unavailable as exc:
                if not cfg.skip_unavailable:
                    raise
                results.update(status="skipped", reason=str(exc))
                log.warning("skipped: %s", exc)
            if results["status"] == "ok":
                if mode == "decompose":
                    _decompose_only(run_obj, results)
                elif mode == "planner_eval":
                    _planner_eval(run_obj, results)
                else:
                    _hierarchical(run_obj, results)
    except BaseException as exc:
        results.update(status="failed", reason=f"{type(exc).__name__}: {exc}")
        raise
    finally:
        results["timings"] = {k: {"seconds": round(v.seconds, 3), "cached": v.cached}
                              for k, v in cache.timings.items()}
        results["wall_seconds"] = round(time.perf_counter() - t_start, 3)
        for line in stage_lines(cache.timings):
            log.info(line)
        write_json_atomic(out_dir / RESULTS_FILE, results)
        tracker.log(_metrics(results))
        tracker.finish()
    summary = {
        "output_dir": str(out_dir),
        "status": results["status"],
        "main_metric": _main_metric(results),
    }
    if cfg.print_table:
        from experiments.results import RunRecord
        from experiments.tables import build_tables

        for tables in build_tables([RunRecord(out_dir / RESULTS_FILE, results)]).values():
            for table in tables:
                print(table.markdown())
        print(f"results: {out_dir / RESULTS_FILE}")
    return summary


def _main_metric(results: dict[str, Any]) -> float | None:
    """Average success; planner exact match for planner-eval runs; mIoU for decomposition runs."""
    if results.get("average_success") is not None:
        return results["average_success"]
    pe = results.get("planner_eval") or {}
    if pe:
        return pe.get("finetuned_exact_match", pe.get("base_exact_match"))
    return (results.get("decomposition") or {}).get("miou")


def _metrics(results: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if results.get("average_success") is not None:
        out["success/average"] = results["average_success"]
    for task, row in (results.get("per_task") or {}).items():
        out[f"success/{task}"] = row["success_rate"]
    for name in ("base", "finetuned"):
        value = (results.get("planner_eval") or {}).get(f"{name}_exact_match")
        if value is not None:
            out[f"planner/{name}_exact_match"] = value
    dec = results.get("decomposition") or {}
    if dec.get("miou") is not None:
        out["decomposition/miou"] = dec["miou"]
    for name, t in (results.get("timings") or {}).items():
        out[f"time/{name}"] = t["seconds"]
    return out


def _decomposition_block(rows: list[dict[str, Any]]) -> dict[str, Any]:
    per_task: dict[str, list[float]] = {}
    for r in rows:
        per_task.setdefault(r["task"], []).append(r["miou"])
    return {
        "miou": float(np.mean([r["miou"] for r in rows])) if rows else None,
        "per_task": {t: float(np.mean(v)) for t, v in per_task.items()},
        "num_demos": len(rows),
        "demos": [{k: r[k] for k in ("episode", "task", "num_frames", "segments", "instructions",
                                     "expert_segments", "miou", "novelty", "seconds")} for r in rows],
    }


def _decompose_only(run: Run, results: dict[str, Any]) -> None:
    if not finetunes(run.cfg):
        raise ValueError("mode=decompose needs a decomposer (decomposer=none decomposes nothing)")
    rows, _ = run.decompositions(run.eval_tasks)
    results["tasks"] = run.eval_tasks
    results["decomposition"] = _decomposition_block(rows)


def _hierarchical(run: Run, results: dict[str, Any]) -> None:
    from experiments.evaluation import evaluate

    # While another job of the sweep trains the policy, this one builds its planner meanwhile.
    policy = run.policy_stage(wait=False)
    seeds = [comp.test_seed(i) for i in run.evaluation_seeds(int(run.cfg.eval.episodes_per_task))]
    if run.planner_learned():
        base_dir, adapter_dir, planner_key, info = run.planner_stage()
        if "decompositions" in info:
            results["decomposition"] = _decomposition_block(info["decompositions"])
        view = comp.planner_view(run.cfg.planner)

        def make_planner() -> Any:
            return comp.load_planner(run.cfg.planner, base_dir, adapter_dir)
    else:
        plans, planner_key, plan_rows = run.oracle_plans(seeds)
        results["oracle"] = {"expert_success": {
            t: float(np.mean([r["expert_success"] for r in plan_rows if r["task"] == t]))
            for t in run.eval_tasks}}
        planner_cls = target_callable(run.cfg.planner, "planner")
        view = str(getattr(planner_cls, "view", "front"))

        def make_planner() -> Any:
            return instantiate_component(run.cfg.planner, "planner", plans=plans)
    policy_dir, policy_key = policy or run.policy_stage()
    loaded: dict[str, Any] = {}

    def models() -> tuple[Any, Any]:
        # Loaded on the first uncached task only: a finished config reruns without loading them.
        if not loaded:
            loaded["policy"] = comp.load_policy(run.cfg.policy, policy_dir, run.text_cache())
            loaded["planner"] = make_planner()
        return loaded["planner"], loaded["policy"]

    episodes: list[dict[str, Any]] = []
    for task in run.eval_tasks:
        spec = {"planner": planner_key, "policy": policy_key, "env": run.node("env"), "task": task,
                "seeds": seeds, "max_steps": int(run.cfg.eval.max_steps)}

        def build(tmp: Path, task=task) -> None:
            planner, policy = models()
            rows = evaluate(run.cfg.env, task, seeds, planner, policy, int(run.cfg.eval.max_steps),
                            view=view)
            write_json_atomic(tmp / "episodes.json", [r.to_dict() for r in rows])

        path, _ = run.cache.get_or_build("evaluation", spec, build, code=comp.task_sources(task))
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


def _planner_eval(run: Run, results: dict[str, Any]) -> None:
    """Exact match of the next instruction at the held-out test episodes' segment starts.

    Base and finetuned planner are scored on the same examples: the expert-segmented, labelled
    test-split episodes of each evaluation task, queried as in the closed loop (image, goal,
    previous instruction), one stage per task.
    """
    if not run.planner_learned():
        raise ValueError("mode=planner_eval scores a trained planner; planner=oracle has nothing to score")
    base_dir, adapter_dir, planner_key, info = run.planner_stage()
    if "decompositions" in info:
        results["decomposition"] = _decomposition_block(info["decompositions"])
    n = int(run.cfg.planner_eval.episodes_per_task)
    loaded: dict[str, Any] = {}

    def planners() -> dict[str, Any]:
        if not loaded:
            loaded["base"] = comp.load_planner(run.cfg.planner, base_dir, None)
            if adapter_dir is not None:
                loaded["finetuned"] = comp.load_planner(run.cfg.planner, base_dir, adapter_dir)
        return loaded

    rows: list[dict[str, Any]] = []
    for task in run.eval_tasks:
        eps, test_key = run.expert_labels(task, "test", n)
        # rows: 2 since each row carries its goal (image-dependent boundaries are found from it)
        spec = {"planner": planner_key, "base": info["base"], "test": test_key, "rows": 2}

        def build(tmp: Path, eps=eps) -> None:
            examples = comp.planner_test_examples(run.cfg.planner, eps)
            out = [{"task": e.task, "episode": e.episode, "frame": int(e.frame), "goal": e.goal,
                    "previous": e.previous_instruction, "target": e.target} for e in examples]
            for name, planner in planners().items():
                preds, hits = planner.hits(examples)
                for row, p, h in zip(out, preds, hits, strict=True):
                    row[name] = p
                    row[f"{name}_hit"] = bool(h)
            write_json_atomic(tmp / "boundaries.json", out)

        path, _ = run.cache.get_or_build("planner_eval", spec, build)
        rows += read_json(path / "boundaries.json")
    results.update(tasks=run.eval_tasks, planner=planner_key,
                   planner_eval=_planner_eval_block(rows, run.eval_tasks, finetuned=adapter_dir is not None))


def image_dependent(rows: list[dict[str, Any]]) -> list[bool]:
    """Per boundary: whether its text cannot settle it, i.e. another boundary of the same task with
    the same goal and previous instruction has a different target (only the image tells them apart)."""
    targets: dict[tuple, set[str]] = {}
    for r in rows:
        targets.setdefault((r["task"], r["goal"], r["previous"]), set()).add(r["target"])
    return [len(targets[(r["task"], r["goal"], r["previous"])]) > 1 for r in rows]


def _rate(rows: list[dict[str, Any]], name: str) -> float | None:
    return float(np.mean([r[f"{name}_hit"] for r in rows])) if rows else None


def _planner_eval_block(rows: list[dict[str, Any]], tasks: list[str], finetuned: bool) -> dict[str, Any]:
    names = ["base", "finetuned"] if finetuned else ["base"]
    for r, dep in zip(rows, image_dependent(rows), strict=True):
        r["image_dependent"] = dep
    dep_rows = [r for r in rows if r["image_dependent"]]
    per_task = {}
    for task in tasks:
        rs = [r for r in rows if r["task"] == task]
        ds = [r for r in rs if r["image_dependent"]]
        per_task[task] = {"boundaries": len(rs), **{n: _rate(rs, n) for n in names},
                          "image_dependent": {"boundaries": len(ds), **{n: _rate(ds, n) for n in names},
                                              "which": sorted({(r["previous"], r["target"]) for r in ds})}}
    block: dict[str, Any] = {
        "per_task": per_task,
        "boundaries": len(rows),
        **{f"{n}_exact_match": _rate(rows, n) for n in names},
        "image_dependent_boundaries": len(dep_rows),
        **{f"{n}_image_dependent": _rate(dep_rows, n) for n in names},
        "misses": [r for r in rows if not r.get("finetuned_hit", r["base_hit"])],
    }
    return block
