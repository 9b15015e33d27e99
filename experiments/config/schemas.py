"""Typed schema of the harness configuration, registered in Hydra's ConfigStore.

The primary config (``conf/config.yaml``) starts its defaults list with ``base_config`` (the
``RunConfig`` dataclass below), so a misspelt or mistyped top-level key
(``sed=1``, ``eval.episodes_per_task=many``, ``mode=trian``) fails when Hydra composes the config,
before any work starts. Keys added with ``+`` and the component groups (decomposer, encoder, ...),
which are ``_target_`` nodes, are checked by ``experiments.config.validate.validate_config`` (keys against
the target's signature, values against its type hints) before any stage runs. Every numeric field
declares its accepted range here, beside its default (:func:`ranged`); the validator checks them all.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field
from enum import Enum
from typing import Any

from hydra.core.config_store import ConfigStore

from envs.generate import SPLIT_SEEDS

# The field metadata key of a range: (low, high), inclusive, None for an open end.
RANGE = "range"
# Episodes of one task in one split: each split's seed range holds this many.
SPLIT_SIZE = min(len(r) for r in SPLIT_SEEDS.values())


def ranged(default: Any = MISSING, *, low: float | None = None, high: float | None = None,
           default_factory: Any = MISSING) -> Any:
    """A dataclass field whose number (each number, for a list; null passes) lies in ``[low, high]``."""
    given = {"default": default} if default_factory is MISSING else {"default_factory": default_factory}
    return field(**given, metadata={RANGE: (low, high)})


class Mode(Enum):
    """What one run does."""

    hierarchical = "hierarchical"  # full pipeline and closed-loop evaluation (success rates)
    decompose = "decompose"  # decompose the validation demos only (mIoU against the expert)
    speed = "speed"  # solver wall time versus number of frames, with and without L_max
    # next-instruction exact match of the base and finetuned planner on held-out test episodes
    planner_eval = "planner_eval"


@dataclass
class DataConfig:
    """How many scripted demonstrations each stage gets."""

    # expert-segmented: policy training set and sub-task database
    train_episodes_per_task: int = ranged(4, low=1, high=SPLIT_SIZE)
    # M: demonstrations decomposed to finetune the planner
    val_episodes_per_task: int = ranged(3, low=1, high=SPLIT_SIZE)
    # Index of the first of those M validation demos: abl_demos's disjoint single-demo sets (0, 1, 2).
    val_first_episode: int = ranged(0, low=0, high=SPLIT_SIZE - 1)
    # base planner pretraining (pretraining tasks only)
    pretrain_episodes_per_task: int = ranged(4, low=1, high=SPLIT_SIZE)
    # Tasks the base planner is pretrained on; null = the env's pretraining tasks (never evaluated).
    pretrain_tasks: list[str] | None = None
    # Tasks whose training sub-tasks fill the database; null = the run's evaluation tasks.
    # abl_ood_beta decomposes tasks outside this list (out-of-distribution for RDD).
    database_tasks: list[str] | None = None


@dataclass
class EvalConfig:
    """Closed-loop evaluation: seeds come from the env's test split, disjoint from demo seeds."""

    episodes_per_task: int = ranged(2, low=1, high=SPLIT_SIZE)
    # planner/policy steps (one sub-task each) before an episode counts as failed; RACER's 25
    # leaves room to replan after the longest expert plan here (stack_blocks with 3 blocks: 18)
    max_steps: int = ranged(25, low=1)
    # Evaluation episode i of run seed s uses test-split seed index s * seed_stride + i.
    seed_stride: int = ranged(1000, low=1)


@dataclass
class PlannerEvalConfig:
    """mode=planner_eval: which held-out episodes score the planner."""

    # test-split expert demos per evaluation task; every segment start is one scored query
    episodes_per_task: int = ranged(10, low=1, high=SPLIT_SIZE)


@dataclass
class SpeedConfig:
    """The solver scaling measurement (mode=speed)."""

    frames: list[int] = ranged(default_factory=lambda: [100, 200, 500, 1000], low=2)
    max_len: int = ranged(100, low=1)
    database_size: int = ranged(2000, low=1)
    dim: int = ranged(256, low=1)
    repeats: int = ranged(1, low=1)


@dataclass
class WandbConfig:
    """Weights & Biases logging; ``offline`` needs no account, ``disabled`` skips it."""

    mode: str = "offline"
    project: str = "rdd-harness"
    entity: str | None = None
    group: str | None = None
    tags: list[str] = field(default_factory=list)


@dataclass
class PathsConfig:
    """Where cached stages live (shared by every run, so reruns do no work)."""

    cache_dir: str = ".cache/rdd"


@dataclass
class RunConfig:
    """Top-level schema of ``conf/config.yaml``."""

    # Evaluation seeds must stay in the test split too: experiments.config.validate.check_relations.
    seed: int = ranged(0, low=0)
    mode: Mode = Mode.hierarchical
    # Evaluation tasks; null = every evaluation task of the env (pretraining tasks excluded).
    tasks: list[str] | None = None
    views: list[str] = field(default_factory=lambda: ["front", "wrist"])
    # Torch threads per job; null = all cores for a single run, cores / parallel jobs in a sweep.
    threads: int | None = ranged(None, low=1)
    # An unavailable component (e.g. an encoder without its weights) records a skipped run
    # with the reason instead of failing (abl_encoder sweeps over encoders that may be absent).
    skip_unavailable: bool = False
    print_table: bool = True
    data: DataConfig = field(default_factory=DataConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    speed: SpeedConfig = field(default_factory=SpeedConfig)
    planner_eval: PlannerEvalConfig = field(default_factory=PlannerEvalConfig)
    wandb: WandbConfig = field(default_factory=WandbConfig)
    paths: PathsConfig = field(default_factory=PathsConfig)
    # Where results.json goes when the pipeline runs outside Hydra (tests); Hydra runs use hydra.run.dir.
    output_dir: str | None = None
    # Component groups: ``_target_`` nodes filled from conf/<group>/<option>.yaml.
    env: Any = None
    encoder: Any = None
    index: Any = None
    decomposer: Any = None
    labeler: Any = None  # labels the decomposed demonstrations (every decomposer alike)
    # Labels the expert-segmented training set (policy data and database entries); a node of its
    # own because the retrieval labeler needs that database to exist first.
    train_labeler: Any = None
    policy: Any = None
    planner: Any = None


# The groups whose options are `_target_` nodes (experiments.config.validate checks them against their target).
COMPONENT_GROUPS = ("env", "encoder", "index", "decomposer", "labeler", "train_labeler", "policy",
                    "planner")


def register_configs() -> None:
    """Store the schema as ``base_config`` (idempotent)."""
    ConfigStore.instance().store(name="base_config", node=RunConfig)


register_configs()
