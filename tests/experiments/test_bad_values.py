"""Harness values out of range fail before any stage (issue 39), naming the key and the range:
``eval.episodes_per_task=-1`` no longer runs to a results.json with 0 episodes, ``seed=-5`` no
longer trains for 43 s first, ``threads=0`` is no torch RuntimeError."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

import experiments.schemas  # noqa: F401  (registers base_config)
from experiments.pipeline import run
from experiments.schemas import RANGE, RunConfig
from experiments.validate import ConfigError, validate_config

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
    ("policy.train.kappa_end=-1", "policy.train: policy train.kappa_end must be > 0"),
])
def test_out_of_range_fails_before_any_stage(tmp_path, override, expect):
    out, cache = tmp_path / "out", tmp_path / "cache"
    cfg = _compose(["experiment=smoke", f"output_dir={out}", f"paths.cache_dir={cache}", override])
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
