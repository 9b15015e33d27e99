"""Launcher plumbing that needs no cluster: the install line, Ray's options, threads per job."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
INSTALL_LINE = "pip install -c constraints.txt -e '.[cluster]'"


def test_cluster_launcher_without_its_extra_names_the_install_line(monkeypatch: pytest.MonkeyPatch):
    sys.path.insert(0, str(ROOT))
    try:
        import run
    finally:
        sys.path.remove(str(ROOT))
    import importlib.util

    real = importlib.util.find_spec
    missing = {"hydra_plugins.hydra_submitit_launcher", "ray"}
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in missing else real(name, *a))
    for launcher in ("slurm", "slurm_local", "ray"):
        with pytest.raises(SystemExit) as exc:
            run.check_launcher(["-m", f"hydra/launcher={launcher}", "seed=0,1"])
        assert INSTALL_LINE in str(exc.value) and launcher in str(exc.value)
    run.check_launcher(["-m", "hydra/launcher=local", "seed=0,1"])  # joblib needs no extra
    run.check_launcher(["seed=0"])


def test_ray_launcher_without_ray_names_the_install_line(monkeypatch: pytest.MonkeyPatch):
    from hydra_plugins.rdd_ray_launcher import _core

    monkeypatch.setitem(sys.modules, "ray", None)  # what an environment without Ray sees
    with pytest.raises(ImportError, match=r"hydra/launcher=ray needs Ray: pip install -c constraints"):
        _core._ray()


def test_ray_options_leave_nulls_to_ray():
    from omegaconf import OmegaConf

    from hydra_plugins.rdd_ray_launcher._core import _options

    node = OmegaConf.create({"address": None, "num_cpus": 2, "runtime_env": {"env_vars": {"A": "1"}}})
    assert _options(node) == {"num_cpus": 2, "runtime_env": {"env_vars": {"A": "1"}}}
    assert _options({}) == {}


@pytest.mark.parametrize(("n_jobs", "env", "cpus", "expected"), [
    (2, {}, 8, 4),                               # joblib: the machine split between its jobs
    (-1, {}, 8, 1),                              # joblib n_jobs=-1: one job per core
    (1, {"SLURM_CPUS_PER_TASK": "3"}, 64, 3),    # Slurm: the allocation, not the node's 64 cores
    (1, {"OMP_NUM_THREADS": "1"}, 16, 1),        # Ray sets it to the task's num_cpus
    (1, {"SLURM_CPUS_PER_TASK": "32"}, 4, 4),    # never more than the affinity mask allows
    (1, {}, 6, 6),                               # a single run: every CPU it may use
])
def test_threads_follow_the_launchers_allotment(monkeypatch, n_jobs, env, cpus, expected):
    import os

    from experiments.run.job import default_threads

    for var in ("SLURM_CPUS_PER_TASK", "OMP_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    for var, value in env.items():
        monkeypatch.setenv(var, value)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(cpus)), raising=False)
    assert default_threads(n_jobs) == expected


def test_slurm_command_submits_one_array_task_per_job(tmp_path: Path):
    """The README's Slurm command, against stand-ins for sbatch/srun that record the batch script."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher",
                        reason=f"needs the cluster extra: {INSTALL_LINE}")
    import os
    import subprocess

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    script = tmp_path / "batch.sh"
    for name, body in (("sbatch", f'cp "$1" "{script}"\n'), ("srun", "")):
        (bin_dir / name).write_text(f"#!/bin/sh\n{body}echo '{name}: a stand-in, no cluster here' >&2\nexit 1\n")
        (bin_dir / name).chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "PYTHONPATH": str(ROOT),
           "WANDB_MODE": "disabled"}
    sweep = tmp_path / "sweep"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "run.py"), "-m", "hydra/launcher=slurm", "experiment=table_main_full",
         "decomposer=rdd,uniform", "seed=0,1,2", "hydra.launcher.partition=gpu", "hydra.launcher.mem_gb=32",
         "hydra.launcher.gpus_per_node=1", "hydra.launcher.array_parallelism=4",
         f"paths.cache_dir={tmp_path / 'cache'}", f"hydra.sweep.dir={sweep}"],
        cwd=tmp_path, env=env, text=True, capture_output=True, timeout=300)
    assert proc.returncode != 0 and "sbatch: a stand-in" in proc.stderr  # submission reached sbatch
    lines = set(script.read_text().splitlines())
    expected = {"#SBATCH --array=0-5%4",  # 6 jobs, at most 4 running at once
                "#SBATCH --partition=gpu", "#SBATCH --mem=32GB", "#SBATCH --gpus-per-node=1",
                "#SBATCH --cpus-per-task=4", "#SBATCH --time=240"}  # the config's defaults
    assert expected <= lines, sorted(lines)
    assert any(f"{sys.executable} -u -m submitit.core._submit {sweep}/.submitit/" in line for line in lines)
    assert not (tmp_path / "cache").exists()  # nothing ran here
