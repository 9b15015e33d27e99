"""Harness values out of range fail before any stage (issue 39), naming the key and the range:
``eval.episodes_per_task=-1`` no longer runs to a results.json with 0 episodes, ``seed=-5`` no
longer trains for 43 s first, ``threads=0`` is no torch RuntimeError."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

import experiments.config.schemas  # noqa: F401  (registers base_config)
from experiments.config.schemas import RANGE, RunConfig
from experiments.config.validate import ConfigError, validate_config
from experiments.run.pipeline import run

CONF = Path(__file__).resolve().parents[2] / "conf"


def _compose(overrides: list[str]):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


@pytest.mark.parametrize(("override", "expect"), [
    ("eval.episodes_per_task=-1", "eval.episodes_per_task: expected >= 1 and <= 10000, got -1"),
    ("seed=-5", "seed: expected >= 0, got -5"),
    ("threads=0", "threads: expected >= 1, got 0"),
    ("data.val_first_episode=-1", "data.val_first_episode: expected >= 0 and <= 9999, got -1"),
    ("data.train_episodes_per_task=0", "data.train_episodes_per_task: expected >= 1"),
    ("eval.max_steps=0", "eval.max_steps: expected >= 1, got 0"),
    ("planner_eval.episodes_per_task=20000", "planner_eval.episodes_per_task: expected >= 1 and <= 10000"),
    ("speed.frames=[100,1]", "speed.frames: expected every item >= 2, got [100, 1]"),
    ("seed=10", "seed: expected <= 9 with eval.seed_stride=1000"),
    ("eval.episodes_per_task=2000", "eval.episodes_per_task: expected <= eval.seed_stride=1000"),
    ("planner.pretrain.epochs=0", "planner.pretrain: planner epochs, batch_size and grad_accum must be >= 1"),
    ("policy.train.kappa_end=-1", "policy.train.kappa_end: policy train: option kappa_end must be > 0.0, got -1"),
    # Components' own options: each range declared once by the component (rdd.checks), checked
    # before any stage through its check_options or, for a dataclass, by building it.
    ("decomposer.alpha=nan", "decomposer.alpha: decomposer rdd: option alpha must be a finite number >= 0.0"),
    ("decomposer.min_len=0", "decomposer.min_len: decomposer rdd: option min_len must be >= 1, got 0"),
    ("decomposer.max_len=1", "decomposer.max_len: decomposer rdd: option max_len must be null (unbounded) or >= "
                             "min_len=2, got 1"),
    ("decomposer=uniform decomposer.n_segments=0", "decomposer.n_segments: decomposer uniform: option n_segments "
                                                   "must be >= 1, got 0"),
    ("decomposer=uvd decomposer.gamma=0", "decomposer.gamma: decomposer uvd: option gamma must be > 0.0, got 0"),
    ("decomposer=rdd_ood decomposer.uvd_options.min_interval=0", "decomposer.uvd_options.min_interval: "),
    ("decomposer=expert decomposer.stopping_delta=-1", "decomposer.stopping_delta: decomposer expert: option"),
    ("decomposer=vlm decomposer.retries=-1", "decomposer.retries: VLM backend openai: option retries must be >= 0"),
    ("env.image_size=0", "env.image_size: env: option image_size must be >= 8 and <= 4096, got 0"),
    ("env.max_steps=0", "env.max_steps: env: option max_steps must be >= 1, got 0"),
    ("env.ticks_per_frame=0", "env.ticks_per_frame: env: option ticks_per_frame must be >= 1, got 0"),
    ("env.motion_timeout=nan", "env.motion_timeout: env: option motion_timeout must be a finite number > 0.0"),
    ("policy.train.epochs=0", "policy.train.epochs: policy train: option epochs must be >= 1, got 0"),
    ("policy.train.lr=inf", "policy.train.lr: policy train: option lr must be a finite number > 0.0, got inf"),
    ("policy.train.anneal_fraction=2", "policy.train.anneal_fraction: policy train: option anneal_fraction must be"),
    ("policy.net.pos_sigma=0", "policy.net.pos_sigma: policy net: option pos_sigma must be > 0.0, got 0"),
    ("policy.net.hidden=0", "policy.net.hidden: policy net: option hidden must be >= 1, got 0"),
    ("policy.data.frames_per_segment=0", "policy.data.frames_per_segment: policy data: option frames_per_segment"),
    ("index.memory_mb=0", "index.memory_mb: index exact: option memory_mb must be >= 1, got 0"),
    ("index=annoy index.search_k=0", "index.search_k: index annoy: option search_k must be -1 (all trees) or >= 1"),
])
def test_out_of_range_fails_before_any_stage(tmp_path, override, expect):
    out, cache = tmp_path / "out", tmp_path / "cache"
    cfg = _compose(["experiment=smoke", f"output_dir={out}", f"paths.cache_dir={cache}", *override.split()])
    with pytest.raises(ConfigError) as info:
        run(cfg)
    assert str(info.value).startswith(expect.split(":")[0] + ":") and expect in str(info.value), str(info.value)
    assert "\n" not in str(info.value)
    assert not out.exists() and not cache.exists()  # nothing written, no stage started


def test_in_range_values_pass(tmp_path):
    base = ["experiment=smoke", f"paths.cache_dir={tmp_path}"]
    validate_config(_compose([*base, "seed=9", "threads=1", "eval.episodes_per_task=1000"]))
    # Only a closed-loop run evaluates on the test split, so only it bounds the seed.
    validate_config(_compose([*base, "mode=decompose", "seed=50"]))


def _numeric(hint) -> bool:
    args = typing.get_args(hint)
    return hint in (int, float) or any(_numeric(a) for a in args if a is not type(None))


def test_every_numeric_option_declares_a_range():
    """Each int/float field of the schema (and each list of them) declares a range beside its default."""
    missing, seen = [], 0
    todo = [("", RunConfig)]
    while todo:
        prefix, schema = todo.pop()
        hints = typing.get_type_hints(schema)
        for f in dataclasses.fields(schema):
            hint = hints[f.name]
            if dataclasses.is_dataclass(hint):
                todo.append((f"{prefix}{f.name}.", hint))
            elif _numeric(hint):
                seen += 1
                if RANGE not in f.metadata:
                    missing.append(prefix + f.name)
    assert seen >= 15 and not missing, missing


def _numbers(node: DictConfig, prefix: str):
    """(dotted key, value) of each number in a component node, nested option mappings included."""
    for key in node:
        if key == "_target_" or node._get_node(key)._is_interpolation():
            continue  # a nested component (``index: ${index}``) is checked under its own group
        value = node[key]
        if prefix == "decomposer" and key == "planner":
            continue  # decomposer=none's planner: its settings are checked as the planner's
        if isinstance(value, DictConfig):
            yield from _numbers(value, f"{prefix}.{key}")
        elif isinstance(value, int | float) and not isinstance(value, bool):
            yield f"{prefix}.{key}", value


# The groups whose options' ranges this project declares (encoders build in preflight, before any
# stage; the planner's settings are its dataclasses', covered above).
CHECKED_GROUPS = ("env", "decomposer", "index", "policy")


@pytest.mark.parametrize("group", CHECKED_GROUPS)
def test_every_numeric_component_option_has_a_range(tmp_path, group):
    """Each number of each option of the group, set far out of range (NaN, or -1e9 for a whole number),
    fails validation naming its key: every component declares a range for every numeric option."""
    checked = 0
    for option in sorted(p.stem for p in (CONF / group).glob("*.yaml")):
        base = ["experiment=smoke", f"paths.cache_dir={tmp_path}", f"{group}={option}"]
        node = _compose(base)[group]
        for key, value in _numbers(node, group):
            bad = "-1000000000" if isinstance(value, int) else "nan"
            with pytest.raises(ConfigError) as info:
                validate_config(_compose([*base, f"{key}={bad}"]))
            assert str(info.value).startswith(f"{key}: "), (option, key, str(info.value))
            checked += 1
        validate_config(_compose(base))  # the shipped values are in range
    assert checked >= 3
