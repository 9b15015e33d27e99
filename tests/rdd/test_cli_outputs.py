"""Outputs of ``python -m rdd`` (issue 39): an output that is, holds or lies inside an input of the
same command is refused, ``--force`` or not; an output that cannot be written fails before the
work, naming the output and never the hidden temporary file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rdd.atomic import check_writable, write_text_atomic
from rdd.cli import main


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _segments_file(path: Path) -> Path:
    path.write_text(json.dumps({"episodes": [{"episode": "ep0", "num_frames": 12, "segments": [[0, 6], [6, 12]]}]}))
    return path


def test_evaluate_never_replaces_its_inputs(tmp_path, cli_fails, monkeypatch):
    gt = _segments_file(tmp_path / "gt.json")
    pred = _segments_file(tmp_path / "pred.json")
    before = gt.read_bytes()
    base = ["evaluate", "--pred", pred, "--gt", gt, "--force"]
    cli_fails(*base, "--out", gt, expect=("--out", "--gt", "gt.json", "--force or not"))
    monkeypatch.chdir(tmp_path)  # ./gt.json and gt.json are one file
    cli_fails("evaluate", "--pred", "pred.json", "--gt", "gt.json", "--force", "--out", "./gt.json",
          expect=("--out gt.json", "--gt gt.json"))
    (tmp_path / "link.json").symlink_to(gt)  # and so are a link and its target
    cli_fails(*base, "--out", "link.json", expect=("--out link.json", "--gt"))
    cli_fails("evaluate", "--pred", f"mine={pred}", "--gt", gt, "--force", "--out", pred,
          expect=("--out", "--pred", "pred.json"))
    assert gt.read_bytes() == before and pred.read_bytes() == before
    assert main([str(a) for a in (*base, "--out", tmp_path / "metrics.json")]) == 0  # elsewhere: fine


def test_build_db_never_writes_over_or_into_its_data(toy_native, tmp_path, cli_fails):
    before = _snapshot(toy_native)
    base = ["build-db", "--format", "native", "--data", toy_native, "--encoder", "pixels", "--no-cache", "--force"]
    cli_fails(*base, "--out", toy_native, expect=("--out", "is the source dataset --data"))
    cli_fails(*base, "--out", toy_native / "db", expect=("--out", "is inside the source dataset --data"))
    cli_fails(*base, "--out", toy_native.parent, expect=("--out", "holds the source dataset --data"))
    cache = tmp_path / "cache"
    cli_fails("build-db", "--format", "native", "--data", toy_native, "--encoder", "pixels", "--cache-dir",
          cache / "emb", "--out", cache, expect=("--out", "holds the embedding cache"))
    assert _snapshot(toy_native) == before and not (toy_native / "db").exists() and not cache.exists()


def test_decompose_never_replaces_a_file_of_its_database(toy_native, tmp_path, cli_fails):
    db = tmp_path / "db"
    assert main(["build-db", "--format", "native", "--data", str(toy_native), "--encoder", "pixels",
                 "--encoder-option", "size=4", "--no-cache", "--no-calibrate", "--out", str(db)]) == 0
    manifest = (db / "manifest.json").read_bytes()
    base = ["decompose", "--format", "native", "--data", toy_native, "--decomposer", "rdd", "--db", db,
            "--encoder-option", "size=4", "--no-cache", "--force"]
    cli_fails(*base, "--out", db / "manifest.json", expect=("--out", "is inside the input --db"))
    cli_fails(*base, "--labeler", "retrieval", "--label-db", db, "--out", db / "entries.json",
          expect=("--out", "is inside the input --db"))
    assert (db / "manifest.json").read_bytes() == manifest
    # A new file beside an input's files changes none of them.
    assert main([str(a) for a in (*base, "--out", db / "segments.json")]) == 0


def test_unwritable_output_fails_before_the_work(unwritable, tmp_path, cli_fails):
    missing = tmp_path / "no-such-data"  # the output is checked first, so this is never reached
    err = cli_fails("decompose", "--format", "native", "--data", missing, "--decomposer", "uniform",
                "--out", unwritable / "x.json", expect=("--out", str(unwritable / "x.json"), "cannot be written"))
    assert ".tmp" not in err and "--data" not in err
    cli_fails("build-db", "--format", "native", "--data", missing, "--encoder", "pixels",
          "--out", unwritable / "sub" / "db", expect=("--out", "cannot be written"))
    cli_fails("evaluate", "--pred", missing, "--gt", missing, "--out", unwritable / "m.json",
          expect=("--out", "cannot be written"))


def test_long_names_fit_or_fail_first(toy_native, tmp_path, cli_fails):
    base = ["decompose", "--format", "native", "--data", toy_native, "--decomposer", "uniform"]
    name = "a" * 250 + ".json"  # fits (255 bytes), though its temporary sibling's plain name would not
    assert main([str(a) for a in (*base, "--out", tmp_path / name)]) == 0
    assert (tmp_path / name).is_file() and [p.name for p in tmp_path.iterdir()] == [name]
    err = cli_fails("decompose", "--format", "native", "--data", tmp_path / "none", "--decomposer", "uniform",
                "--out", tmp_path / ("b" * 300 + ".json"), expect=("--out", "bytes long", "allows"))
    assert "--data" not in err
    cli_fails(*base, "--out", tmp_path / name / "x.json", expect=("--out", "is a file, not a folder"))


def test_atomic_errors_name_the_target(unwritable):
    target = unwritable / "out.json"
    with pytest.raises(OSError) as info:
        write_text_atomic(target, "x")
    assert info.value.filename == str(target) and ".tmp" not in str(info.value)
    with pytest.raises(OSError) as info:
        check_writable(target)
    assert info.value.filename == str(target) and "cannot create files in" in str(info.value)
