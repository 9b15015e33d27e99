"""The stage cache shared by concurrent jobs: built once, killed builds leave nothing, stale locks recovered."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from experiments.cache.locks import FileLock
from experiments.cache.store import StageCache, spec_key

ROOT = Path(__file__).resolve().parents[2]


def _lease_marker(host: str, pid: int, lease_s: float) -> str:
    """The lock file a job on ``host`` writes (filelock's protocol 2 lease record)."""
    return f"filelock/2\npid={pid}\nhost={host}\nmode=lease\ntoken=dead\nduration={lease_s!r}\n"


# One sweep job needing stage "s": it waits for the go file, then asks the cache; its build records
# the builder's pid in a log (one line per build) and holds for a while.
WORKER = r"""
import json, os, sys, time
from pathlib import Path
from experiments.cache.store import StageCache
root, work, hold, beat, stale = sys.argv[1:6]
work = Path(work)
cache = StageCache(Path(root), heartbeat_s=float(beat), stale_after_s=float(stale))
def build(d):
    with open(work / "builds.log", "a") as fh:
        fh.write(f"{os.getpid()}\n")
    (d / "value.txt").write_text(str(os.getpid()))
    (d / "half").mkdir()
    (work / f"started-{os.getpid()}").touch()
    time.sleep(float(hold))
(work / f"ready-{os.getpid()}").touch()
while not (work / "go").exists():
    time.sleep(0.01)
path, key = cache.get_or_build("s", {"a": 1}, build)
print(json.dumps({"path": str(path), "value": (path / "value.txt").read_text(),
                  "cached": cache.timings["s"].cached}))
"""


def _worker(root: Path, work: Path, hold: float, beat: float = 0.2, stale: float = 1.0) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-c", WORKER, str(root), str(work), str(hold), str(beat),
                             str(stale)], env=env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)


def _wait_for(pattern: str, folder: Path, count: int, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while len(list(folder.glob(pattern))) < count:
        assert time.monotonic() < deadline, f"no {pattern} in {folder} after {timeout} s"
        time.sleep(0.02)


def _entries(stage_dir: Path) -> list[str]:
    return sorted(p.name for p in stage_dir.iterdir() if not p.name.startswith("."))


def test_two_jobs_at_once_build_a_stage_once(tmp_path: Path):
    root, work = tmp_path / "cache", tmp_path / "work"
    work.mkdir()
    # The build holds longer than the stale limit: only the holder's heartbeat keeps the waiter off.
    procs = [_worker(root, work, hold=2.5) for _ in range(2)]
    _wait_for("ready-*", work, 2)
    (work / "go").touch()
    outs = [p.communicate(timeout=120) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
    results = [json.loads(o[0]) for o in outs]
    builders = (work / "builds.log").read_text().split()
    assert len(builders) == 1  # built once
    assert results[0]["path"] == results[1]["path"]
    assert {r["value"] for r in results} == {builders[0]}  # both got the one build
    assert sorted(r["cached"] for r in results) == [False, True]
    assert _entries(root / "s") == [spec_key({"a": 1})]
    assert not list((root / "s").glob(".*"))  # no lock file or temporary folder left behind


def test_job_killed_mid_stage_leaves_nothing_and_its_lock_is_recovered(tmp_path: Path):
    root, work = tmp_path / "cache", tmp_path / "work"
    work.mkdir()
    (work / "go").touch()
    victim = _worker(root, work, hold=600)
    _wait_for("started-*", work, 1)
    os.kill(victim.pid, signal.SIGKILL)
    victim.communicate(timeout=60)
    stage = root / "s"
    assert _entries(stage) == []  # nothing a later job could take for a result
    assert list(stage.glob(".*.lock.json")) and list(stage.glob(f".{spec_key({'a': 1})}.*.tmp"))
    # A later job on this host sees the owner's pid is gone and takes over at once, although the
    # stale limit (an hour) is far away; it builds the stage and clears the killed job's leftovers.
    later = _worker(root, work, hold=0, stale=3600)
    out, err = later.communicate(timeout=120)
    assert later.returncode == 0, err[-2000:]
    assert json.loads(out)["value"] == str(later.pid) and json.loads(out)["cached"] is False
    assert (work / "builds.log").read_text().split() == [str(victim.pid), str(later.pid)]
    assert _entries(stage) == [spec_key({"a": 1})]
    assert not list(stage.glob(".*"))


def test_stale_lock_of_a_dead_node_is_taken_over(tmp_path: Path):
    cache = StageCache(tmp_path, heartbeat_s=0.05, stale_after_s=0.5)
    key = spec_key({"a": 1})
    lock = tmp_path / "s" / f".{key}.lock.json"
    lock.parent.mkdir(parents=True)
    # A lock from another host: its pid means nothing here, only its unmoving heartbeat counts.
    lock.write_text(_lease_marker("node-that-died", os.getpid(), 0.5))
    start = time.monotonic()
    path, _ = cache.get_or_build("s", {"a": 1}, lambda d: (d / "x").write_text("built"))
    assert time.monotonic() - start >= 0.5  # it waited the stale limit before taking over
    assert (path / "x").read_text() == "built" and not lock.exists()


def test_a_live_lock_is_never_taken_over(tmp_path: Path):
    path = tmp_path / ".k.lock.json"
    holder = FileLock(path, heartbeat_s=0.05, stale_after_s=0.2)
    assert holder.try_acquire()
    waiter = FileLock(path, heartbeat_s=0.05, stale_after_s=0.2)
    assert not waiter.try_acquire()
    got: list[float] = []

    def wait_then_take() -> None:
        waiter.acquire()
        got.append(time.monotonic())
        waiter.release()

    thread = threading.Thread(target=wait_then_take)
    thread.start()
    time.sleep(1.0)  # five stale limits: the heartbeat keeps the waiter off
    assert not got
    released = time.monotonic()
    holder.release()
    thread.join(timeout=30)
    assert got and got[0] >= released
    assert list(tmp_path.iterdir()) == []


def test_stale_lock_is_taken_over_where_names_cannot_be_exchanged(tmp_path: Path, monkeypatch):
    """NFS and SMB refuse renameat2's exchange, with which filelock swaps a stale marker out."""
    import filelock._soft

    monkeypatch.setattr(filelock._soft, "exchange_names", lambda source, target: False)
    path = tmp_path / ".k.lock.json"
    path.write_text(_lease_marker("node-that-died", os.getpid(), 0.2))
    start = time.monotonic()
    with FileLock(path, heartbeat_s=0.05, stale_after_s=0.2):
        assert time.monotonic() - start >= 0.4  # twice the stale limit
        assert path.exists()
    assert list(tmp_path.iterdir()) == []
