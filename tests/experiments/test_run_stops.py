"""How a harness run fails or stops (issue 39): one line each, nothing left behind that matters.

A read-only stage cache runs on in a temporary folder with one warning; a read-only
``hydra.run.dir`` and a bad value are one line and exit 2; Ctrl-C and SIGTERM during a stage are one
line and exit 130 / 143, after the stage's lock is released and its temporary folder removed."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from experiments.cache.store import SPEC_FILE, StageCache

ROOT = Path(__file__).resolve().parents[2]
RUN = ROOT / "run.py"
SPEED = ["experiment=speed", "speed.frames=[30,60]", "speed.database_size=50", "speed.dim=8",
         "wandb.mode=disabled"]


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "WANDB_MODE": "disabled", "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, str(RUN), *args], cwd=cwd, env=env, text=True,
                          capture_output=True, timeout=300)


def test_unwritable_cache_builds_in_a_temporary_folder(unwritable, caplog):
    with caplog.at_level(logging.WARNING, logger="experiments.cache.store"):
        cache = StageCache.for_run(unwritable / "cache")
    assert cache.temporary and cache.root != unwritable / "cache"
    (line,) = [r.getMessage() for r in caplog.records]
    assert str(unwritable / "cache") in line and str(cache.root) in line and "nothing is reused or kept" in line
    path, _ = cache.get_or_build("probe", {"a": 1}, lambda tmp: (tmp / "x.txt").write_text("x"))
    assert (path / "x.txt").read_text() == "x" and (path / SPEC_FILE).is_file()
    cache.close()
    assert not cache.root.exists()


def test_writable_cache_is_the_shared_one(tmp_path):
    cache = StageCache.for_run(tmp_path / "cache")
    assert not cache.temporary and cache.root == tmp_path / "cache"
    cache.close()
    assert list(tmp_path.iterdir()) == []  # the writability probe leaves nothing


def test_unwritable_run_dir_and_bad_values_are_one_line(unwritable, tmp_path):
    cache = f"paths.cache_dir={tmp_path / 'cache'}"
    proc = _run([*SPEED, cache, f"hydra.run.dir={unwritable / 'run'}"], tmp_path)
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    assert proc.stderr.count("\n") == 1 and f"hydra.run.dir={unwritable / 'run'}: cannot be written" in proc.stderr
    proc = _run([*SPEED, cache, "seed=-5"], tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stdout + proc.stderr
    assert proc.stdout.strip() == "error: seed: expected >= 0, got -5", proc.stdout
    assert not (tmp_path / "cache").exists()


# A stage that is being built when the signal comes: the pipeline's stage cache under run.py's stop handling.
SCRIPT = textwrap.dedent("""
    import signal, sys, time
    from pathlib import Path
    from experiments.run.interrupts import run_stoppable
    from experiments.cache.store import StageCache

    signal.signal(signal.SIGINT, signal.default_int_handler)  # a background parent may ignore SIGINT
    cache = StageCache(Path(sys.argv[1]))
    cache.get_or_build("first", {"a": 1}, lambda tmp: (tmp / "done.txt").write_text("done"))

    def slow(tmp):
        (tmp / "half.txt").write_text("half")
        print("building", flush=True)
        time.sleep(60)

    sys.exit(run_stoppable(lambda: cache.get_or_build("second", {"a": 2}, slow)))
""")


@pytest.mark.parametrize(("sig", "code", "line"), [
    (signal.SIGTERM, 143, "terminated (SIGTERM); the stage cache keeps finished stages, rerun to resume"),
    (signal.SIGINT, 130, "interrupted; the stage cache keeps finished stages, rerun to resume"),
])
def test_stops_are_one_line_after_the_cleanups(tmp_path, sig, code, line):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT, str(tmp_path / "cache")], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout.readline().strip() == "building"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code and err.strip() == line, err
    left = sorted(str(p.relative_to(tmp_path / "cache")) for p in (tmp_path / "cache").rglob("*"))
    # The finished stage stays; the interrupted one left no lock, no temporary folder, no entry.
    assert [p for p in left if p.startswith("second")] == ["second"], left
    assert any(p.startswith("first/") and p.endswith("done.txt") for p in left), left


# A scheduler's kill (slurm, guard) stops wandb's service, which runs in a session of its own, beside
# the harness; the run's own stop must still be one line, not the dead tracker's traceback.
TRACKED = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from types import SimpleNamespace
    from experiments.run.interrupts import run_stoppable
    from experiments.run.tracking import Tracker

    wandb_cfg = SimpleNamespace(mode="offline", project="p", entity=None, group=None, tags=[])
    tracker = Tracker(wandb_cfg, {"seed": 0}, Path(sys.argv[1]), name="stopped")

    def body():
        try:
            print("tracking", flush=True)
            time.sleep(60)
        finally:
            tracker.log({"metric": 1.0})
            tracker.finish()

    sys.exit(run_stoppable(body))
""")


def test_sigterm_after_the_tracker_service_died_is_still_one_line(tmp_path, processes):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "WANDB_MODE": "offline"}
    proc = subprocess.Popen([sys.executable, "-c", TRACKED, str(tmp_path)], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout.readline().strip() == "tracking"
    services = [pid for pid, parent, _ in processes() if parent == proc.pid]
    assert services, "wandb started no service process"
    for child in services:  # the service goes first, as when the whole job is killed
        os.kill(child, signal.SIGKILL)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    lines = err.strip().splitlines()
    assert proc.returncode == 143, err
    assert lines[-1] == "terminated (SIGTERM); the stage cache keeps finished stages, rerun to resume", err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert any("logging service is gone" in line and str(tmp_path) in line for line in lines[:-1]), err
