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

    from experiments.pipeline import _default_threads

    for var in ("SLURM_CPUS_PER_TASK", "OMP_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    for var, value in env.items():
        monkeypatch.setenv(var, value)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(cpus)), raising=False)
    assert _default_threads(n_jobs) == expected
