"""The stage graph of one run: demos, expert labels, policy, sub-task database, and their keys.

Each stage is cached under ``paths.cache_dir`` by the config (and code, see ``stages.py``) that
affects it: episodes per task and split -> expert segmentation + labels -> policy -> sub-task
database (per encoder; + calibration, for a calibrated decomposer only). The planner's stages
built on top of these live in ``planner_stages.py``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from omegaconf import DictConfig, OmegaConf, open_dict

from experiments.cache.code_keys import code_key, target_modules
from experiments.cache.store import StageCache, read_json, spec_key
from experiments.config.instantiate import Resolved, instantiate_component, resolve
from experiments.config.validate import target_callable
from experiments.run import components as comp
from rdd.atomic import write_json_atomic
from rdd.data.episode import Episode
from rdd.data.native import load_episode
from rdd.encoders.cache import EmbeddingCache

T = TypeVar("T")
R = TypeVar("R")


class Unavailable(RuntimeError):
    """A component cannot run on this machine (e.g. an encoder whose weights are absent)."""



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
        self._learned_planner = None
        self._resolved: dict[str, Resolved] = {}
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
                self._encoder = instantiate_component(self.component("encoder"), "encoder")
            except (FileNotFoundError, ImportError, OSError) as exc:
                name = str(self.cfg.encoder.get("_target_", "?")).removesuffix(".build").rsplit(".", 1)[-1]
                raise Unavailable(f"encoder {name!r}: {exc}") from exc
            node = self.node("encoder")
            self._encoder_key = spec_key({"encoder": node, "weights_id": self._encoder.weights_id,
                                          "code": code_key(target_modules(node))})
        return self._encoder

    def encoder_key(self) -> str:
        """Key of the encoder's config and weights."""
        self.encoder()
        assert self._encoder_key is not None
        return self._encoder_key

    def embedding_cache(self):
        """The shared on-disk embedding cache (the runtime object ``cache``)."""
        return EmbeddingCache(Path(self.cfg.paths.cache_dir) / "embeddings")

    # --- stages ----------------------------------------------------------------------------------
    def demos_key(self, task: str) -> str:
        """Key of ``task``'s demos: the env options demos depend on, the env code and the task's module."""
        return spec_key({"env": comp.demo_env_options(self.cfg.env),
                         "code": self.cache.codes.key("demos", comp.task_sources(task))})

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
                ep = load_episode(d)
                self._episode_cache[key] = ep
                self._episode_keys[ep.name] = key
            out.append(self._episode_cache[key])
        return out

    def expert_labels(self, task: str, split: str, count: int, first: int = 0,
                      wait: bool = True) -> tuple[list[Episode], str] | None:
        """Episodes carrying expert segments and labeler instructions (copies), and a key over them
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
            lambda tmp: comp.train_policy(self.component("policy"), eps, self.train_labeler(),
                                          self.text_cache(), tmp), wait=wait)

    def labeler(self):
        """The labeler of decomposed demonstrations, shared by every decomposer (built once)."""
        if self._labeler is None:
            self._labeler = instantiate_component(self.component("labeler"), "labeler", self.runtime("labeler"))
        return self._labeler

    def train_labeler(self):
        """The labeler of the expert-segmented training set (built once)."""
        if self._train_labeler is None:
            self._train_labeler = instantiate_component(self.component("train_labeler"), "train_labeler")
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
        """Whether the decomposer takes its options from the database's calibration (its target is a
        factory marked ``uses_calibration``, as ``RDDDecomposer.calibrated`` is)."""
        node = self.cfg.get("decomposer")
        if node is None or not node.get("_target_"):
            return False
        return bool(getattr(self.component("decomposer").target, "uses_calibration", False))

    def component(self, group: str) -> Resolved:
        """The component node of ``group``, resolved and checked once per run."""
        if group not in self._resolved:
            self._resolved[group] = resolve(self.cfg[group], group)
        return self._resolved[group]

    def runtime(self, group: str) -> dict[str, Any]:
        """The runtime objects the component of ``group`` takes, each under its one name."""
        build = {"database": self.database, "encoder": self.encoder, "cache": self.embedding_cache}
        return {name: build[name]() for name in self.component(group).runtime}

    def planner_learned(self) -> bool:
        """Whether the planner is a trained model (base + LoRA stages) rather than the oracle."""
        return bool(getattr(self.component("planner").target, "learned", True))

    def learned_planner(self):
        """The learned planner of the config (its settings and training steps), built once per run."""
        if self._learned_planner is None:
            self._learned_planner = instantiate_component(self.component("planner"), "planner")
        return self._learned_planner

    def decomposes(self) -> bool:
        """Whether this run decomposes the validation demos (to finetune a learned planner)."""
        return finetunes(self.cfg) and self.planner_learned()

    def runtime_key_parts(self, group: str) -> dict[str, Any]:
        """What a component's output depends on besides its config: the runtime objects it takes."""
        node = self.cfg.get(group)
        parts: dict[str, Any] = {group: self.node(group)}
        if node is None or not node.get("_target_"):
            return parts
        takes = self.component(group).runtime
        if "encoder" in takes or "database" in takes:
            parts["encoder"] = self.encoder_key()
        if "database" in takes:
            self.database()
            parts["database"] = self._database_key
        return parts

    def val_window(self) -> tuple[int, int]:
        """(M, first): the validation demos ``first .. first+M-1`` the planner is finetuned on."""
        return int(self.cfg.data.val_episodes_per_task), int(self.cfg.data.val_first_episode)

    def evaluation_seeds(self, n: int) -> list[int]:
        """Test-split seed indices of this run's evaluation episodes (kept inside the test split and
        apart from other seeds' by experiments.config.validate.check_relations, before any stage)."""
        base = int(self.cfg.seed) * int(self.cfg.eval.seed_stride)
        return [base + i for i in range(n)]


def with_segments(episode: Episode, segments: list, instructions: list[str]) -> Episode:
    """A copy of ``episode`` carrying ``segments`` and their ``instructions`` (the cached one stays as is)."""
    return dataclasses.replace(episode, segments=[tuple(int(v) for v in s) for s in segments],
                               instructions=list(instructions), meta=dict(episode.meta))


def with_row_planner(cfg: DictConfig) -> DictConfig:
    """``cfg`` with the planner its decomposer option evaluates instead of ``planner`` (decomposer=none:
    the vanilla VLM of the paper's w/o-finetune row), so that every stage sees that one planner."""
    node = cfg.get("decomposer")
    if node is None or "planner" not in node:
        return cfg
    with open_dict(cfg):
        planner = cfg.get("planner")
        if planner is None or getattr(target_callable(planner, "planner"), "learned", True):
            cfg.planner = node.planner  # the oracle, no learned planner, keeps its plans
        del cfg.decomposer.planner
    return cfg


def finetunes(cfg: DictConfig) -> bool:
    """Whether the planner is finetuned: decomposer `none` (no _target_) keeps the base planner."""
    node = cfg.get("decomposer")
    return node is not None and bool(node.get("_target_"))
