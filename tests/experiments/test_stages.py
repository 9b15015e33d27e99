"""Stage cache: keyed by spec, built once, atomic."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.stages import StageCache, spec_key


def test_stage_built_once_and_keyed_by_spec(tmp_path: Path):
    cache = StageCache(tmp_path)
    calls = []

    def build(d: Path) -> None:
        calls.append(d)
        (d / "out.txt").write_text("x")

    p1, k1 = cache.get_or_build("s", {"a": 1, "b": [1, 2]}, build)
    p2, k2 = cache.get_or_build("s", {"b": [1, 2], "a": 1}, build)  # same spec, other order
    assert (p1, k1) == (p2, k2) and len(calls) == 1
    assert (p1 / "out.txt").read_text() == "x"
    assert json.loads((p1 / "spec.json").read_text()) == {"a": 1, "b": [1, 2]}
    assert cache.timings["s"].cached is False  # first call built it
    p3, k3 = cache.get_or_build("s", {"a": 2, "b": [1, 2]}, build)
    assert k3 != k1 and len(calls) == 2
    # A fresh cache object (a rerun) finds the entry without building.
    again = StageCache(tmp_path)
    again.get_or_build("s", {"a": 1, "b": [1, 2]}, build)
    assert len(calls) == 2 and again.timings["s"].cached is True


def test_failed_build_leaves_nothing(tmp_path: Path):
    cache = StageCache(tmp_path)

    def boom(d: Path) -> None:
        (d / "partial").write_text("half")
        raise RuntimeError("stage failed")

    with pytest.raises(RuntimeError, match="stage failed"):
        cache.get_or_build("s", {"a": 1}, boom)
    assert not cache.path("s", spec_key({"a": 1})).exists()
    assert [p.name for p in (tmp_path / "s").iterdir() if not p.name.startswith(".")] == []


def test_spec_key_rejects_objects():
    with pytest.raises(TypeError, match="cannot put"):
        spec_key({"a": object()})


def test_code_fingerprint_follows_source_contents(tmp_path: Path):
    from experiments.stages import code_fingerprint

    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text("x = 1\n")
    (tmp_path / "pkg" / "notes.txt").write_text("not code")
    first = code_fingerprint(("pkg",), tmp_path)
    (tmp_path / "pkg" / "notes.txt").write_text("other notes")
    code_fingerprint.cache_clear()
    assert code_fingerprint(("pkg",), tmp_path) == first  # only Python sources count
    (tmp_path / "pkg" / "a.py").write_text("x = 2\n")
    code_fingerprint.cache_clear()
    assert code_fingerprint(("pkg",), tmp_path) != first
    with pytest.raises(FileNotFoundError, match="STAGE_CODE"):
        code_fingerprint(("missing",), tmp_path)
    code_fingerprint.cache_clear()


def test_code_fingerprint_leaves_out_excluded_files(tmp_path: Path):
    from experiments.stages import code_fingerprint

    (tmp_path / "pkg" / "sub").mkdir(parents=True)
    (tmp_path / "pkg" / "a.py").write_text("x = 1\n")
    (tmp_path / "pkg" / "labels.py").write_text("y = 1\n")
    (tmp_path / "pkg" / "sub" / "b.py").write_text("z = 1\n")
    paths = ("pkg", "!pkg/labels.py", "!pkg/sub")
    first = code_fingerprint(paths, tmp_path)
    (tmp_path / "pkg" / "labels.py").write_text("y = 2\n")
    (tmp_path / "pkg" / "sub" / "b.py").write_text("z = 2\n")
    code_fingerprint.cache_clear()
    assert code_fingerprint(paths, tmp_path) == first
    (tmp_path / "pkg" / "a.py").write_text("x = 2\n")
    code_fingerprint.cache_clear()
    assert code_fingerprint(paths, tmp_path) != first
    code_fingerprint.cache_clear()


def test_a_file_named_inside_an_excluded_folder_counts(tmp_path: Path):
    from experiments.stages import code_fingerprint

    (tmp_path / "pkg" / "tasks").mkdir(parents=True)
    (tmp_path / "pkg" / "tasks" / "base.py").write_text("x = 1\n")
    (tmp_path / "pkg" / "tasks" / "other.py").write_text("y = 1\n")
    paths = ("pkg", "!pkg/tasks", "pkg/tasks/base.py")
    first = code_fingerprint(paths, tmp_path)
    (tmp_path / "pkg" / "tasks" / "other.py").write_text("y = 2\n")
    code_fingerprint.cache_clear()
    assert code_fingerprint(paths, tmp_path) == first
    (tmp_path / "pkg" / "tasks" / "base.py").write_text("x = 2\n")
    code_fingerprint.cache_clear()
    assert code_fingerprint(paths, tmp_path) != first
    code_fingerprint.cache_clear()


def test_each_task_keys_its_stages_by_its_own_module():
    pytest.importorskip("pybullet")
    from envs.tasks import task_sources
    from experiments.stages import stage_code_key

    # a task's module and the task modules it imports (the shared cabinet), never the registry
    assert task_sources("open_drawer") == ["envs/tasks/base.py", "envs/tasks/cabinet.py",
                                           "envs/tasks/open_drawer.py"]
    assert task_sources("push_buttons") == ["envs/tasks/base.py", "envs/tasks/push_buttons.py"]
    keys = {t: stage_code_key("demos", tuple(task_sources(t))) for t in ("open_drawer", "push_buttons")}
    assert keys["open_drawer"] != keys["push_buttons"] != stage_code_key("demos")
    with pytest.raises(KeyError, match="unknown task"):
        task_sources("no_such_task")


def test_every_stage_key_covers_its_code(tmp_path: Path):
    from experiments.stages import STAGE_CODE, stage_code_key

    for stage in STAGE_CODE:  # every listed path exists in the repository
        assert len(stage_code_key(stage)) == 16
    cache = StageCache(tmp_path)
    path, key = cache.get_or_build("planner_base", {"a": 1}, lambda d: None)
    recorded = json.loads((path / "spec.json").read_text())
    assert recorded["code"] == stage_code_key("planner_base")
    assert key == spec_key({"a": 1, "code": stage_code_key("planner_base")}) != spec_key({"a": 1})


def test_one_line_per_stage_says_built_or_reused(tmp_path: Path):
    from experiments.logs import stage_lines

    cache = StageCache(tmp_path)
    for task in ("a", "b"):
        cache.get_or_build("labels", {"task": task}, lambda d: (d / "x").write_text("1"))
    cache.get_or_build("policy", {"p": 1}, lambda d: (d / "x").write_text("1"))
    first = stage_lines(cache.timings)
    assert [line.split()[1:3] for line in first] == [["labels", "built"], ["policy", "built"]]

    again = StageCache(tmp_path)
    again.get_or_build("labels", {"task": "a"}, lambda d: None)   # cached
    again.get_or_build("labels", {"task": "c"}, lambda d: (d / "x").write_text("1"))  # new
    again.get_or_build("policy", {"p": 1}, lambda d: None)
    lines = stage_lines(again.timings)
    assert len(lines) == 2
    assert "built 1, reused 1" in lines[0] and lines[0].split()[1] == "labels"
    assert lines[1].split()[1:3] == ["policy", "reused"] and lines[1].endswith(" s")
