"""Faults of what is stored (issue 62): a database read while another process replaces it, and
damaged files. A load gives the old or the new database whole, never a mix and never a false
"corrupt"; a damaged database file is one line naming it; a damaged resume part is redone with a
warning; damaged caches are recomputed with a warning, never used."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from rdd.database.model import DatabaseError, SubtaskDatabase
from rdd.testing.trees import tree_bytes

ROOT = Path(__file__).resolve().parents[2]


def two_databases(n: int = 40, d: int = 6) -> tuple[SubtaskDatabase, SubtaskDatabase]:
    """Two databases of the same shape whose every file differs."""
    out = []
    for k, name in enumerate("ab"):
        rng = np.random.default_rng(k)
        out.append(SubtaskDatabase.from_arrays(
            rng.normal(size=(n, d)), rng.normal(size=(n, d)), np.full(n, k + 3), [name] * n,
            {"encoder": "pixels", "weights_id": name, "views": ["front"], "episodes": [f"{name}{i}" for i in range(n)]}))
    return out[0], out[1]


REBUILD = """
import sys, time
from pathlib import Path
sys.path.insert(0, {tests!r})
from test_faults_stores import two_databases
a, b = two_databases()
root, stop = Path({root!r}), Path({stop!r})
k = 0
while not stop.exists():
    (a if k % 2 else b).save(root, overwrite=True)
    k += 1
    Path({count!r}).write_text(str(k))
"""


def test_a_load_during_rebuilds_gives_one_database_whole(tmp_path):
    a, b = two_databases()
    root = tmp_path / "db"
    a.save(root)
    stop, count = tmp_path / "stop", tmp_path / "count"
    code = textwrap.dedent(REBUILD).format(tests=str(Path(__file__).parent), root=str(root), stop=str(stop),
                                           count=str(count))
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stderr=subprocess.PIPE, text=True)
    seen = {"a": 0, "b": 0}
    try:
        while not count.exists():
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.01)
        loads = 0
        while loads < 20000 and (loads < 200 or int(count.read_text() or 0) < 30):
            loads += 1
            db = SubtaskDatabase.load(root)
            name = db.labels[0]
            want = a if name == "a" else b
            assert set(db.labels) == {name} and db.meta["weights_id"] == name
            assert db.episodes == want.episodes and np.array_equal(db.durations, want.durations)
            assert np.array_equal(db.begin, want.begin) and np.array_equal(db.end, want.end)
            seen[name] += 1
    finally:
        stop.touch()
        proc.wait(timeout=60)
    assert proc.returncode == 0, proc.stderr.read()
    assert int(count.read_text()) >= 30 and seen["a"] and seen["b"], (count.read_text(), seen)


def test_a_damaged_database_file_is_one_line_naming_it(native_six, tmp_path, cli_fails):
    a, _ = two_databases()
    root = a.save(tmp_path / "db")
    good = (root / "end.npy").read_bytes()
    raw = bytearray(good)
    raw[-3] ^= 0x01
    (root / "end.npy").write_bytes(bytes(raw))
    with pytest.raises(DatabaseError, match=f"database file {root / 'end.npy'} is corrupt .*rebuild the database"):
        SubtaskDatabase.load(root)
    cli_fails("decompose", "--format", "native", "--data", str(native_six), "--decomposer", "rdd", "--db", str(root),
              "--out", str(tmp_path / "x.json"), expect=(f"{root / 'end.npy'} is corrupt", "rebuild the database"))
    (root / "end.npy").write_bytes(good)
    (root / "entries.json").unlink()
    with pytest.raises(DatabaseError, match=f"database file {root / 'entries.json'} is missing"):
        SubtaskDatabase.load(root)


def test_a_damaged_resume_part_is_redone(native_six, tmp_path, caplog):
    from rdd.cli import main

    def argv(out: Path) -> list[str]:
        return ["decompose", "--format", "native", "--data", str(native_six), "--decomposer", "uniform",
                "--option", "n_segments=3", "--out", str(out)]

    out = tmp_path / "out.json"
    assert main(argv(tmp_path / "ref.json")) == 0
    import rdd.cli.decompose as decompose

    original = decompose._decompose_one
    done: list[str] = []

    def stop_at_three(state, path, episode, payload):
        if len(done) == 3:
            raise KeyboardInterrupt
        done.append(episode.name)
        original(state, path, episode, payload)

    decompose._decompose_one = stop_at_three
    try:
        assert main(argv(out)) == 130
    finally:
        decompose._decompose_one = original
    parts = sorted((tmp_path / ".out.json.parts").glob("*.json"))
    assert len(parts) == 3
    parts[0].write_text(parts[0].read_text()[:20])  # truncated
    parts[1].write_text(json.dumps({"episode": "someone else", "record": {}}))
    with caplog.at_level(logging.WARNING):
        assert main(argv(out)) == 0
    warned = [r.getMessage() for r in caplog.records if "cannot be read back" in r.getMessage()]
    assert len(warned) == 2 and str(parts[0]) in " ".join(warned), warned
    assert out.read_bytes() == (tmp_path / "ref.json").read_bytes()


def test_a_damaged_staged_file_of_the_lerobot_copy_is_written_again(lerobot_copy_argv, tmp_path, monkeypatch, caplog):
    import rdd.data.lerobot.write as writer
    from rdd.cli import main

    argv = lerobot_copy_argv
    assert main(argv("ref")) == 0
    original = writer._rewrite_data_file
    done: list[str] = []

    def stop_after_one(source, *args, **kwargs):
        if done:
            raise KeyboardInterrupt
        done.append(source.name)
        return original(source, *args, **kwargs)

    monkeypatch.setattr(writer, "_rewrite_data_file", stop_after_one)
    assert main(argv("copy")) == 130
    monkeypatch.undo()
    (staged,) = (tmp_path / ".copy.parts").rglob(done[0])
    staged.write_bytes(staged.read_bytes()[:200])  # truncated by a disk fault
    with caplog.at_level(logging.WARNING):
        assert main(argv("copy")) == 0
    assert any(f"staged file {staged} of the LeRobot copy cannot be read back" in r.getMessage()
               for r in caplog.records), caplog.text
    assert tree_bytes(tmp_path / "copy") == tree_bytes(tmp_path / "ref")
