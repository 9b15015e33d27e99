"""Concurrent jobs of a cold sweep split the work instead of waiting on each other's stages."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

import experiments.config.schemas  # noqa: F401  (registers base_config)
from experiments.cache.locks import FileLock
from experiments.cache.store import SPEC_FILE, StageCache, spec_key

CONF = Path(__file__).resolve().parents[2] / "conf"


def _held_elsewhere(cache: StageCache, stage: str, key: str) -> FileLock:
    """A lock taken as another job would (a lock file naming a live owner)."""
    lock = FileLock(cache.root / stage / f".{key}.lock.json")
    (cache.root / stage).mkdir(parents=True, exist_ok=True)
    assert lock.try_acquire()
    return lock


def test_get_or_build_without_waiting_leaves_a_busy_entry_to_its_builder(tmp_path: Path):
    cache = StageCache(tmp_path)
    calls = []

    def build(tmp: Path) -> None:
        calls.append(tmp)
        (tmp / "out.txt").write_text("x")

    key = spec_key({"n": 1})
    other = _held_elsewhere(cache, "thing", key)
    assert cache.get_or_build("thing", {"n": 1}, build, wait=False) is None
    assert calls == [] and not cache.path("thing", key).exists()
    other.release()
    path, got = cache.get_or_build("thing", {"n": 1}, build, wait=False)
    assert got == key and (path / "out.txt").read_text() == "x" and (path / SPEC_FILE).is_file()
    # finished: found without any lock, even while someone holds the key's lock
    other = _held_elsewhere(cache, "thing", key)
    assert cache.get_or_build("thing", {"n": 1}, build, wait=False) == (path, key)
    other.release()
    assert len(calls) == 1
    with cache.lock("thing", "k2", wait=False) as held:
        assert held is True
        with cache.lock("thing", "k2", wait=False) as again:
            assert again is False


def test_labelled_set_makes_the_free_tasks_demos_while_another_job_makes_one(tmp_path: Path):
    pytest.importorskip("pybullet")
    from experiments.run.graph import Run

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config",
                      overrides=["experiment=smoke", f"paths.cache_dir={tmp_path / 'cache'}"])
    cache = StageCache(tmp_path / "cache")
    run = Run(cfg, tmp_path / "out", cache)
    busy, free, split = "open_drawer", "close_jar", "train"
    other = _held_elsewhere(cache, "demos", f"{run.demos_key(busy)}-{busy}-{split}")
    result: dict = {}
    worker = threading.Thread(target=lambda: result.update(out=run.labelled_set([busy, free], split, 1)))
    worker.start()
    free_demo = cache.root / "demos" / run.demos_key(free) / split / free
    deadline = time.monotonic() + 300
    while not list(free_demo.glob("*/episode.json")):  # made while the busy task is still held
        assert worker.is_alive() and time.monotonic() < deadline, "the free task's demo never came"
        time.sleep(0.2)
    assert not (cache.root / "demos" / run.demos_key(busy) / split / busy).exists()
    other.release()  # the other job is done: this one now makes (here) the busy task's demo too
    worker.join(timeout=300)
    episodes, _key = result["out"]
    assert [ep.task for ep in episodes] == [busy, free]  # the caller's order, whoever made them


def test_each_free_first_takes_free_items_then_waits_for_busy_ones():
    from experiments.run.graph import each_free_first

    calls = []

    def attempt(item: str, wait: bool) -> str | None:
        calls.append((item, wait))
        if item == "busy" and not wait:
            return None  # another job holds it
        return item.upper()

    done = each_free_first(["busy", "a", "b", "a"], attempt)
    assert done == {"busy": "BUSY", "a": "A", "b": "B"}
    # free ones first without waiting; the busy one is tried again, then waited for
    assert calls == [("busy", False), ("a", False), ("b", False), ("busy", False), ("busy", True)]


def test_database_parts_are_built_per_task_while_another_job_holds_one(tmp_path: Path):
    pytest.importorskip("pybullet")
    from experiments.run.graph import Run
    from rdd.database.model import SubtaskDatabase

    busy, free = "open_drawer", "turn_tap"
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config",
                      overrides=["experiment=smoke", f"tasks=[{busy},{free}]", "data.train_episodes_per_task=1",
                                 "encoder=pixels", f"paths.cache_dir={tmp_path / 'cache'}"])
    cache = StageCache(tmp_path / "cache")
    run = Run(cfg, tmp_path / "out", cache)
    other = _held_elsewhere(cache, "demos", f"{run.demos_key(busy)}-{busy}-train")
    worker = threading.Thread(target=run.database)
    worker.start()
    parts = cache.root / "database_part"
    deadline = time.monotonic() + 300
    while not list(parts.glob(f"*/{SPEC_FILE}")):  # the free task's part, made while the busy one is held
        assert worker.is_alive() and time.monotonic() < deadline, "the free task's part never came"
        time.sleep(0.2)
    assert not (cache.root / "database").exists()
    other.release()
    worker.join(timeout=300)
    assert len(list(parts.glob(f"*/{SPEC_FILE}"))) == 2
    db = run.database()
    assert sorted(set(db.tasks)) == [busy, free] and db.tasks[0] == busy  # the tasks' order, not the build order
    # the merged database is the one a single build over both tasks' episodes makes
    eps, _ = run.labelled_set([busy, free], "train", 1)
    whole = SubtaskDatabase.build(eps, None, run.encoder(), views=tuple(run.views), cache=run.embedding_cache())
    assert whole.labels == db.labels and whole.episodes == db.episodes
    assert (whole.begin == db.begin).all() and (whole.end == db.end).all()
