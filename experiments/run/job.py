"""The job a run executes in: Hydra's view of it, its share of the CPUs, the hardware it reports."""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from rdd.machine import cpu_model


def hydra_info() -> tuple[Path | None, dict[str, Any], list[str], bool, int]:
    """(output dir, group choices, task overrides, is multirun, parallel jobs) from Hydra if active."""
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
    except (ImportError, ValueError):
        return None, {}, [], False, 1
    choices = {k: v for k, v in OmegaConf.to_container(hc.runtime.choices).items()
               if not k.startswith("hydra")}
    multirun = hc.mode == RunMode.MULTIRUN
    n_jobs = int(OmegaConf.select(hc, "launcher.n_jobs", default=1) or 1) if multirun else 1
    return Path(hc.runtime.output_dir), choices, list(hc.overrides.task), multirun, n_jobs


def set_threads(cfg: DictConfig, n_jobs: int) -> int:
    """Set torch's thread count to ``cfg.threads`` (default: this job's share) and return it."""
    import torch

    threads = cfg.threads
    if threads is None:
        threads = default_threads(n_jobs)
    torch.set_num_threads(int(threads))
    return int(threads)


def default_threads(n_jobs: int) -> int:
    """Torch threads for a job: its share of the CPUs it may use, as its launcher allotted them.

    joblib sweeps split this machine between ``n_jobs``; a Slurm job gets ``SLURM_CPUS_PER_TASK``,
    a Ray task ``OMP_NUM_THREADS`` (Ray sets it to the task's ``num_cpus``); otherwise every CPU in
    the process's affinity mask (a cgroup or ``taskset`` limit), not every core of the node.
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if n_jobs <= 0:  # joblib's n_jobs=-1: one job per core
        return 1
    if n_jobs > 1:
        return max(1, cores // n_jobs)
    for var in ("SLURM_CPUS_PER_TASK", "OMP_NUM_THREADS"):
        value = os.environ.get(var, "")
        if value.isdigit() and int(value) > 0:
            return min(int(value), cores)
    return max(1, cores)


def hardware() -> dict[str, Any]:
    """The machine and library versions a run reports in its results."""
    import torch

    return {
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        # trained stages round differently on another CPU model or vector width: say which made them
        "cpu_model": cpu_model(),
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cuda": bool(torch.cuda.is_available()),
    }
