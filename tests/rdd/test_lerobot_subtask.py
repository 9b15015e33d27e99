"""Task and sub-task kept apart (issue 43, point 2): an unannotated episode's entries carry its task,
never as their instruction, so writing sub-tasks needs a labeler or a fallback and says so."""

from __future__ import annotations

import json

import pytest

from rdd.cli import main
from rdd.data.lerobot.reader import load_episodes
from rdd.database.model import SubtaskDatabase

pytest.importorskip("pyarrow")
pytest.importorskip("av")
TASK = "stack the cups"  # tests/rdd/conftest.py's task string


def test_unannotated_entries_keep_the_task_and_no_instruction(lerobot_factory, tmp_path, capsys):
    src = lerobot_factory("v2.1")
    enc = ["--encoder-option", "size=4", "--cache-dir", str(tmp_path / "cache")]
    assert main(["build-db", "--format", "lerobot", "--data", str(src), "--encoder", "pixels", *enc,
                 "--out", str(tmp_path / "db")]) == 0
    db = SubtaskDatabase.load(tmp_path / "db")
    assert db.meta["source"]["segmenter"] == "expert"
    assert db.labels == [""] * len(db) and db.tasks == [TASK] * len(db)
    # rdd over that database gives no sub-task: writing takes a labeler (signals by default) or a fallback
    rdd = ["decompose", "--format", "lerobot", "--data", src, "--decomposer", "rdd", "--db", tmp_path / "db", *enc]
    def fails(*extra, expect: tuple[str, ...]) -> None:
        capsys.readouterr()
        assert main([str(a) for a in (*rdd, *extra)]) == 2
        errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error")]
        assert len(errors) == 1 and all(w in errors[0] for w in expect), errors
        assert not (tmp_path / "none").exists()

    # with neither option, the signals labeler names what the gripper and arm do (its default)
    assert main([str(a) for a in (*rdd, "--out", tmp_path / "s.json", "--write-lerobot", tmp_path / "sig")]) == 0
    sig = json.loads((tmp_path / "s.json").read_text())["episodes"]
    assert all(r["instruction_sources"] == ["labeler"] * len(r["segments"]) for r in sig)
    assert all(i and i != TASK for r in sig for i in r["instructions"])
    fails("--labeler", "retrieval", "--write-lerobot", tmp_path / "none", expect=("--label-db", "instructions"))
    assert main([str(a) for a in (*rdd, "--fallback-instruction", "{task}: part {index}", "--out",
                                  tmp_path / "r.json", "--write-lerobot", tmp_path / "out")]) == 0
    recs = json.loads((tmp_path / "r.json").read_text())["episodes"]
    back = {e.name: e for e in load_episodes(tmp_path / "out")}
    for r in recs:
        n = len(r["segments"])
        assert r["instruction_sources"] == ["fallback"] * n
        assert r["instructions"] == [f"{TASK}: part {i}" for i in range(1, n + 1)]
        assert back[r["episode"]].instructions == r["instructions"] and back[r["episode"]].task == TASK
