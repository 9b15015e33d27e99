"""Bad values given to ``python -m rdd`` (issue 39): each is one line naming the flag, option, file
or field as the user gave it, with the accepted range, and nothing is written."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from rdd.cli import main
from rdd.decomposers.uniform import UniformDecomposer
from rdd.errors import InputError


@pytest.fixture(scope="module")
def db(toy_native, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("db") / "db"
    assert main(["build-db", "--format", "native", "--data", str(toy_native), "--encoder", "pixels", "--encoder-option",
                 "size=4", "--no-cache", "--calibration-sample", "2", "--out", str(out)]) == 0
    return out


def test_rdd_options_name_the_flag_typed_and_the_range(toy_native, db, tmp_path, cli_fails):
    out = tmp_path / "x.json"
    base = ["decompose", "--format", "native", "--data", toy_native, "--decomposer", "rdd", "--db", db,
            "--encoder-option", "size=4", "--no-cache", "--out", out]
    for alpha in ("nan", "inf", "-inf", "1e308", "-0.5"):
        cli_fails(*base, f"--alpha={alpha}", expect=("--alpha", "alpha must be", ">= 0.0 and <= 1000000.0"))
    cli_fails(*base, "--max-len", "0", expect=("--max-len 0", "max_len must be >= 1"), absent=("--option",))
    cli_fails(*base, "--option", "min_len=0", expect=("--option min_len=0", "min_len must be >= 1"))
    cli_fails(*base, "--option", "min_len=3", "--max-len", "2",
          expect=("--max-len 2", "max_len must be null (unbounded) or >= min_len=3"))
    cli_fails(*base, "--option", "beta=NaN", expect=("--option beta=NaN", "beta must be a finite number"))
    cli_fails(*base, "--option", "mode=odd", expect=("--option mode=\"odd\"", "mode must be one of"))
    assert not out.exists()
    assert main([str(a) for a in (*base, "--alpha", "0.5", "--max-len", "8")]) == 0  # in range: fine


def test_other_flags_and_grids_name_themselves(toy_native, db, tmp_path, cli_fails):
    cli_fails("build-db", "--format", "native", "--data", toy_native, "--encoder", "pixels", "--no-cache",
          "--stopping-delta", "-1", "--out", tmp_path / "db2", expect=("--stopping-delta -1", "stopping_delta must be"),
          absent=("--option",))
    cli_fails("decompose", "--format", "native", "--data", toy_native, "--decomposer", "expert", "--stopping-delta",
          "nan", "--out", tmp_path / "x.json", expect=("--stopping-delta nan", "finite number >= 0.0"))
    cli_fails("calibrate", "--db", db, "--alpha", "0,nan", expect=("--alpha 0,nan", "<= 1000000.0"))
    cli_fails("calibrate", "--db", db, "--min-len", "0", expect=("--min-len 0", "min_len"))
    assert not (tmp_path / "db2").exists() and not (tmp_path / "x.json").exists()
    with pytest.raises(InputError, match="n_segments must be a whole number >= 1") as info:
        UniformDecomposer(n_segments=math.inf)
    assert info.value.option == "n_segments"


def test_a_view_named_twice_is_refused(toy_native, db, tmp_path, cli_fails):
    cli_fails("build-db", "--format", "native", "--data", toy_native, "--encoder", "pixels", "--no-cache",
          "--views", "front", "front", "--out", tmp_path / "db2", expect=("--views front front", "['front']"))
    cli_fails("decompose", "--format", "native", "--data", toy_native, "--decomposer", "rdd", "--db", db,
          "--encoder-option", "size=4", "--no-cache", "--views", "front", "wrist", "front",
          "--out", tmp_path / "x.json", expect=("--views front wrist front",))
    cli_fails("decompose", "--format", "native", "--data", toy_native, "--decomposer", "uvd", "--encoder", "pixels",
          "--no-cache", "--views", "wrist", "wrist", "--out", tmp_path / "x.json", expect=("--views",))
    assert not (tmp_path / "db2").exists() and not (tmp_path / "x.json").exists()


@pytest.mark.parametrize("template", ["{task.__class__.__mro__}", "{task!r}", "{episode[0]}", "{0}", "{}",
                                      "{index:{task}}", "{__import__}", "{task"])
def test_fallback_fields_are_plain_names_only(toy_native, tmp_path, cli_fails, template):
    out = tmp_path / "x.json"
    cli_fails("decompose", "--format", "native", "--data", toy_native, "--decomposer", "uniform", "--option",
          "n_segments=2", "--fallback-instruction", template, "--out", out,
          expect=("--fallback-instruction", "{task}, {episode}, {index}"))
    assert not out.exists()


def test_fallback_plain_fields_with_a_format_spec_work(toy_native, tmp_path):
    out = tmp_path / "x.json"
    assert main(["decompose", "--format", "native", "--data", str(toy_native), "--decomposer", "uniform", "--option",
                 "n_segments=2", "--fallback-instruction", "{task}: step {index:02d} of {count} [{start},{end})",
                 "--out", str(out)]) == 0
    rec = json.loads(out.read_text())["episodes"][0]
    assert rec["instructions"] == ["toy: step 01 of 2 [0,6)", "toy: step 02 of 2 [6,12)"]


@pytest.mark.parametrize(("field", "value"), [
    ("segments", [["0", "6"], ["6", "12"]]),
    ("segments", [[0, 6.5], [6.5, 12]]),
    ("segments", [[0.0, 6], [6, 12]]),
    ("segments", [[0, True], [1, 12]]),
    ("segments", [[0, 6, 7], [7, 12]]),
    ("segments", "0-12"),
    ("num_frames", "12"),
    ("num_frames", 12.0),
])
def test_segments_files_are_not_coerced(tmp_path, cli_fails, field, value):
    good = {"episode": "ep0", "num_frames": 12, "segments": [[0, 6], [6, 12]]}
    (tmp_path / "gt.json").write_text(json.dumps({"episodes": [good]}))
    (tmp_path / "pred.json").write_text(json.dumps({"episodes": [{**good, field: value}]}))
    for pred, gt in (("pred.json", "gt.json"), ("gt.json", "pred.json")):  # both readers: --pred and --gt
        cli_fails("evaluate", "--pred", tmp_path / pred, "--gt", tmp_path / gt, "--out", tmp_path / "m.json",
              expect=("pred.json", "episodes[0]", f"field '{field}'"))
    assert not (tmp_path / "m.json").exists()
