"""The Hydra app end to end: output directories, results.json, fail-fast errors, smoke multirun."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RUN = ROOT / "run.py"


def _run(args: list[str], cwd: Path, timeout: int = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "WANDB_MODE": "disabled", "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, str(RUN), *args], cwd=cwd, env=env, text=True,
                          capture_output=True, timeout=timeout)


SPEED = ["experiment=speed", "speed.frames=[30,60]", "speed.database_size=50", "speed.dim=8",
         "wandb.mode=disabled"]


def test_speed_runs_write_results_in_unique_dirs(tmp_path: Path):
    cache = f"paths.cache_dir={tmp_path / 'cache'}"
    # Two runs started together must not share an output directory.
    env = {**os.environ, "WANDB_MODE": "disabled", "PYTHONPATH": str(ROOT)}
    procs = [subprocess.Popen([sys.executable, str(RUN), *SPEED, cache, f"seed={s}"], cwd=tmp_path,
                              env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
             for s in (0, 1)]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs), outs
    results = sorted(tmp_path.glob("outputs/*/*/results.json"))
    assert len(results) == 2
    seeds = set()
    for path in results:
        data = json.loads(path.read_text())
        seeds.add(data["seed"])
        assert data["status"] == "ok" and data["mode"] == "speed"
        assert [r["frames"] for r in data["speed"]["rows"]] == [30, 60]
        assert data["config"]["speed"]["database_size"] == 50  # the resolved config rides along
        assert (path.parent / "config_resolved.json").is_file()
        assert data["timings"]["speed"]["seconds"] > 0
    assert seeds == {0, 1}
    assert "Frames T" in outs[0]  # the table is printed
    from experiments.tables import main

    assert main(["--runs", str(tmp_path / "outputs")]) == 0
    assert (tmp_path / "outputs" / "tables" / "speed.md").is_file()


def test_typo_fails_before_any_work(tmp_path: Path):
    proc = _run(["eval.episodes_per_tsk=3", f"paths.cache_dir={tmp_path / 'cache'}"], tmp_path)
    assert proc.returncode != 0
    assert "episodes_per_tsk" in proc.stderr + proc.stdout
    assert not (tmp_path / "cache").exists()


def test_missing_encoder_weights_fail_at_once(tmp_path: Path):
    pytest.importorskip("rdd.encoders.liv", reason="the liv encoder module is not in this checkout")
    weights = tmp_path / "no-weights"
    env_var = {"RDD_WEIGHTS_DIR": str(weights)}
    env = {**os.environ, **env_var, "WANDB_MODE": "disabled", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, str(RUN), "encoder=liv", "wandb.mode=disabled",
                           f"paths.cache_dir={tmp_path / 'cache'}"], cwd=tmp_path, env=env,
                          text=True, capture_output=True, timeout=300)
    assert proc.returncode != 0
    text = proc.stdout + proc.stderr
    assert "liv" in text.lower() and str(weights) in text
    # Nothing long ran: no demonstration was generated.
    assert not (tmp_path / "cache" / "episodes").exists()
    data = json.loads(next(tmp_path.glob("outputs/*/*/results.json")).read_text())
    assert data["status"] == "failed" and "liv" in data["reason"].lower()


@pytest.mark.slow
def test_smoke_multirun_produces_its_table(tmp_path: Path):
    sweep = tmp_path / "sweep"
    proc = _run(["-m", "experiment=smoke", "decomposer=rdd,uniform", "seed=0,1",
                 f"paths.cache_dir={tmp_path / 'cache'}", f"hydra.sweep.dir={sweep}"], tmp_path,
                timeout=3600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = sorted(sweep.glob("*/results.json"))
    assert len(results) == 4
    for path in results:
        data = json.loads(path.read_text())
        assert data["status"] == "ok"
        assert len(data["episodes"]) == 2 and {e["task"] for e in data["episodes"]} == set(data["tasks"])
        for ep in data["episodes"]:
            assert set(ep) >= {"task", "seed", "success", "steps", "instructions"}
        assert 0.0 <= data["decomposition"]["miou"] <= 1.0
    from experiments.tables import write_tables

    md, written = write_tables(sweep)
    rows = [line for line in md.splitlines() if line.startswith("| rdd") or line.startswith("| uniform")
            or line.startswith("| **rdd") or line.startswith("| **uniform")]
    assert len(rows) >= 2, md
    assert any(p.suffix == ".tex" for p in written)
    # A rerun of a finished configuration finds every stage in the cache.
    again = _run(["experiment=smoke", "decomposer=uniform", "seed=0",
                  f"paths.cache_dir={tmp_path / 'cache'}", "hydra.run.dir=" + str(tmp_path / "rerun")],
                 tmp_path, timeout=1200)
    assert again.returncode == 0, again.stderr[-3000:]
    timings = json.loads((tmp_path / "rerun" / "results.json").read_text())["timings"]
    assert timings and all(t["cached"] for t in timings.values()), timings
