"""Outputs of ``python -m rdd`` (issue 39): an output that is, holds or lies inside an input of the
same command is refused, ``--force`` or not; an output that cannot be written fails before the
work, naming the output and never the hidden temporary file."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

from rdd.atomic import check_writable, write_text_atomic
from rdd.cli import main
from rdd.data.episode import Episode
from rdd.data.native import save_episode


def _episode(name: str, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 255, size=(12, 8, 8, 3), dtype=np.uint8)
    grip = np.repeat([1.0, 0.0, 1.0], 4)
    return Episode(name=name, views={"front": frames, "wrist": frames[:, ::-1].copy()}, gripper_open=grip,
                   joint_velocities=np.ones((12, 7)), goal="toy", task="toy")


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("native") / "ds"
    for k in range(2):
        save_episode(_episode(f"ep{k}", k), root / f"ep{k}")
    return root


@pytest.fixture
def unwritable(tmp_path) -> Path:
    """A folder this process cannot create files in (root ignores modes: then /sys, mounted read-only)."""
    if os.geteuid() != 0:
        folder = tmp_path / "ro"
        folder.mkdir()
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)
        return
    try:
        fd, probe = tempfile.mkstemp(dir="/sys")
    except OSError:
        yield Path("/sys")
        return
    os.close(fd)
    os.unlink(probe)
    pytest.skip("no folder here refuses a new file to root")


def fails(capsys, *argv, expect: tuple[str, ...]) -> str:
    """Run the CLI; assert exit 2 and one line on stderr naming each of ``expect``; return it."""
    capsys.readouterr()
    assert main([str(a) for a in argv]) == 2, argv
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for word in expect:
        assert word in err, (word, err)
    return err


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _segments_file(path: Path) -> Path:
    path.write_text(json.dumps({"episodes": [{"episode": "ep0", "num_frames": 12, "segments": [[0, 6], [6, 12]]}]}))
    return path


def test_evaluate_never_replaces_its_inputs(tmp_path, capsys, monkeypatch):
    gt = _segments_file(tmp_path / "gt.json")
    pred = _segments_file(tmp_path / "pred.json")
    before = gt.read_bytes()
    base = ["evaluate", "--pred", pred, "--gt", gt, "--force"]
    fails(capsys, *base, "--out", gt, expect=("--out", "--gt", "gt.json", "--force or not"))
    monkeypatch.chdir(tmp_path)  # ./gt.json and gt.json are one file
    fails(capsys, "evaluate", "--pred", "pred.json", "--gt", "gt.json", "--force", "--out", "./gt.json",
          expect=("--out gt.json", "--gt gt.json"))
    (tmp_path / "link.json").symlink_to(gt)  # and so are a link and its target
    fails(capsys, *base, "--out", "link.json", expect=("--out link.json", "--gt"))
    fails(capsys, "evaluate", "--pred", f"mine={pred}", "--gt", gt, "--force", "--out", pred,
          expect=("--out", "--pred", "pred.json"))
    assert gt.read_bytes() == before and pred.read_bytes() == before
    assert main([str(a) for a in (*base, "--out", tmp_path / "metrics.json")]) == 0  # elsewhere: fine


def test_build_db_never_writes_over_or_into_its_data(data, tmp_path, capsys):
    before = _snapshot(data)
    base = ["build-db", "--format", "native", "--data", data, "--encoder", "pixels", "--no-cache", "--force"]
    fails(capsys, *base, "--out", data, expect=("--out", "is the source dataset --data"))
    fails(capsys, *base, "--out", data / "db", expect=("--out", "is inside the source dataset --data"))
    fails(capsys, *base, "--out", data.parent, expect=("--out", "holds the source dataset --data"))
    cache = tmp_path / "cache"
    fails(capsys, "build-db", "--format", "native", "--data", data, "--encoder", "pixels", "--cache-dir",
          cache / "emb", "--out", cache, expect=("--out", "holds the embedding cache"))
    assert _snapshot(data) == before and not (data / "db").exists() and not cache.exists()


def test_decompose_never_replaces_a_file_of_its_database(data, tmp_path, capsys):
    db = tmp_path / "db"
    assert main(["build-db", "--format", "native", "--data", str(data), "--encoder", "pixels",
                 "--encoder-option", "size=4", "--no-cache", "--no-calibrate", "--out", str(db)]) == 0
    manifest = (db / "manifest.json").read_bytes()
    base = ["decompose", "--format", "native", "--data", data, "--decomposer", "rdd", "--db", db,
            "--encoder-option", "size=4", "--no-cache", "--force"]
    fails(capsys, *base, "--out", db / "manifest.json", expect=("--out", "is inside the input --db"))
    fails(capsys, *base, "--labeler", "retrieval", "--label-db", db, "--out", db / "entries.json",
          expect=("--out", "is inside the input --db"))
    assert (db / "manifest.json").read_bytes() == manifest
    # A new file beside an input's files changes none of them.
    assert main([str(a) for a in (*base, "--out", db / "segments.json")]) == 0


def test_unwritable_output_fails_before_the_work(unwritable, tmp_path, capsys):
    missing = tmp_path / "no-such-data"  # the output is checked first, so this is never reached
    err = fails(capsys, "decompose", "--format", "native", "--data", missing, "--decomposer", "uniform",
                "--out", unwritable / "x.json", expect=("--out", str(unwritable / "x.json"), "cannot be written"))
    assert ".tmp" not in err and "--data" not in err
    fails(capsys, "build-db", "--format", "native", "--data", missing, "--encoder", "pixels",
          "--out", unwritable / "sub" / "db", expect=("--out", "cannot be written"))
    fails(capsys, "evaluate", "--pred", missing, "--gt", missing, "--out", unwritable / "m.json",
          expect=("--out", "cannot be written"))


def test_long_names_fit_or_fail_first(data, tmp_path, capsys):
    base = ["decompose", "--format", "native", "--data", data, "--decomposer", "uniform"]
    name = "a" * 250 + ".json"  # fits (255 bytes), though its temporary sibling's plain name would not
    assert main([str(a) for a in (*base, "--out", tmp_path / name)]) == 0
    assert (tmp_path / name).is_file() and [p.name for p in tmp_path.iterdir()] == [name]
    err = fails(capsys, "decompose", "--format", "native", "--data", tmp_path / "none", "--decomposer", "uniform",
                "--out", tmp_path / ("b" * 300 + ".json"), expect=("--out", "bytes long", "allows"))
    assert "--data" not in err
    fails(capsys, *base, "--out", tmp_path / name / "x.json", expect=("--out", "is a file, not a folder"))


def test_atomic_errors_name_the_target(unwritable):
    target = unwritable / "out.json"
    with pytest.raises(OSError) as info:
        write_text_atomic(target, "x")
    assert info.value.filename == str(target) and ".tmp" not in str(info.value)
    with pytest.raises(OSError) as info:
        check_writable(target)
    assert info.value.filename == str(target) and "cannot create files in" in str(info.value)
