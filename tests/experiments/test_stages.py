"""Stage cache: keyed by spec, built once, atomic."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.cache.store import StageCache, spec_key


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


def test_one_line_per_stage_says_built_or_reused(tmp_path: Path):
    from experiments.run.logs import stage_lines

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


def test_a_resumable_build_keeps_what_it_saved_across_a_failure(tmp_path: Path):
    """A killed build's saves stay for the next build of the same key; a finished entry drops them."""
    cache = StageCache(tmp_path)
    seen: list[list[str]] = []

    def build(d: Path, saves: Path, fail: bool) -> None:
        saves.mkdir(parents=True, exist_ok=True)
        seen.append(sorted(p.name for p in saves.iterdir()))
        (saves / f"part{len(seen)}").write_text("saved")
        if fail:
            raise RuntimeError("killed")
        (d / "out.txt").write_text("done")

    with pytest.raises(RuntimeError, match="killed"):
        cache.get_or_build("s", {"a": 1}, lambda d, s: build(d, s, True), resumable=True)
    path, key = cache.get_or_build("s", {"a": 1}, lambda d, s: build(d, s, False), resumable=True)
    assert seen == [[], ["part1"]]  # the second build found the first one's save
    assert (path / "out.txt").read_text() == "done"
    assert not cache.progress_path("s", key).exists()
    assert cache.get_or_build("s", {"a": 1}, lambda d, s: build(d, s, True), resumable=True) == (path, key)


def test_a_finished_resumable_entry_drops_saves_left_beside_it(tmp_path: Path):
    """Saves left by a kill between an entry's rename and their removal go at the next lookup."""
    cache = StageCache(tmp_path)
    path, key = cache.get_or_build("s", {"a": 1}, lambda d, s: (d / "out.txt").write_text("x"), resumable=True)
    left = cache.progress_path("s", key)
    left.mkdir()
    (left / "state.pt").write_text("old")
    assert cache.get_or_build("s", {"a": 1}, lambda d, s: None, resumable=True) == (path, key)
    assert not left.exists() and (path / "out.txt").read_text() == "x"
