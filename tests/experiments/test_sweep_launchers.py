"""Sweeps through the cluster launchers: submitit (Slurm's code path, run locally) and Ray give the
same results and tables as the joblib launcher, sharing one stage cache."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
INSTALL = "needs the cluster extra: pip install -c constraints.txt -e '.[cluster]'"

# The smoke experiment shrunk further (short policy and planner training): the test is about the
# launchers, the stage cache shared by their jobs, and the tables, not about the numbers.
SMOKE = ["experiment=smoke", "decomposer=uniform", "seed=0,1", "threads=1",
         "policy.train.epochs=5", "policy.train.min_steps=50",
         "planner.pretrain.epochs=3", "planner.finetune.epochs=3"]
LAUNCHERS = {
    "slurm_local": ["hydra/launcher=slurm_local"],
    "ray": ["hydra/launcher=ray", "hydra.launcher.init.num_cpus=2",
            "hydra.launcher.init.object_store_memory=100000000"],
    "joblib": [],  # the default launcher (conf/hydra/launcher/local.yaml)
}


def _sweep(tmp_path: Path, name: str, extra: list[str]) -> Path:
    sweep = tmp_path / name
    start = time.monotonic()
    env = {**os.environ, "WANDB_MODE": "disabled", "PYTHONPATH": str(ROOT), "RAY_AUTH_MODE": "disabled"}
    env.pop("RDD_CACHE_DIR", None)
    proc = subprocess.run([sys.executable, str(ROOT / "run.py"), "-m", *SMOKE, *extra,
                           f"paths.cache_dir={tmp_path / 'cache'}", f"hydra.sweep.dir={sweep}"],
                          cwd=tmp_path, env=env, text=True, capture_output=True, timeout=600)
    assert proc.returncode == 0, f"{name}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    print(f"{name} sweep: {time.monotonic() - start:.0f} s")  # for the log (-s), never asserted
    return sweep


def _results(sweep: Path) -> dict[int, dict]:
    out = {}
    for path in sorted(sweep.glob("*/results.json")):
        data = json.loads(path.read_text())
        assert data["status"] == "ok", path
        out[data["seed"]] = data
    return out


@pytest.mark.slow
def test_submitit_and_ray_sweeps_match_joblib(tmp_path: Path):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher", reason=INSTALL)
    pytest.importorskip("ray", reason=INSTALL)
    from experiments.tables import main as tables_main

    sweeps, results = {}, {}
    for name, extra in LAUNCHERS.items():
        # Every launcher's jobs run their own closed-loop evaluation; the stages upstream of it
        # (demos, policy, planners) come from the cache the first sweep filled.
        shutil.rmtree(tmp_path / "cache" / "evaluation", ignore_errors=True)
        sweeps[name] = _sweep(tmp_path, name, extra)
        results[name] = _results(sweeps[name])
        assert sorted(results[name]) == [0, 1], name
        timings = [r["timings"] for r in results[name].values()]
        assert all(not t["evaluation"]["cached"] for t in timings), name
        if name != "slurm_local":
            assert all(t["policy"]["cached"] and t["planner_finetune"]["cached"] for t in timings)
        assert tables_main(["--runs", str(sweeps[name])]) == 0  # the aggregation CLI, as a lab runs it
    assert (sweeps["slurm_local"] / ".submitit").is_dir()  # the jobs really went through submitit

    reference = results["joblib"]
    for name in ("slurm_local", "ray"):
        for seed, data in results[name].items():
            # Same seeds, same episodes: success, steps and every instruction the planner gave.
            assert data["episodes"] == reference[seed]["episodes"], (name, seed)
            assert data["per_task"] == reference[seed]["per_task"]
            assert data["overrides"] == reference[seed]["overrides"]
        tables = sorted(p.name for p in (sweeps[name] / "tables").iterdir())
        assert tables == sorted(p.name for p in (sweeps["joblib"] / "tables").iterdir())
        for table in tables:
            if table.endswith((".md", ".tex")):
                assert (sweeps[name] / "tables" / table).read_text() == \
                    (sweeps["joblib"] / "tables" / table).read_text(), (name, table)
