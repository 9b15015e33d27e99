"""The Ray side of :class:`RayLauncher`, imported only when a sweep starts (it needs ``ray``)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

from hydra_plugins.rdd_ray_launcher import INSTALL_LINE

log = logging.getLogger(__name__)


def _ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise ImportError(f"hydra/launcher=ray needs Ray: {INSTALL_LINE}") from exc
    return ray


def _options(node: DictConfig | dict[str, Any]) -> dict[str, Any]:
    """A plain dict of the options that are set (null means: leave it to Ray)."""
    opts = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)
    return {k: v for k, v in opts.items() if v is not None}


def _run_on_worker(idx: int, sweep_config: DictConfig, hydra_context: HydraContext,
                   task_function: TaskFunction, singleton_state: dict[Any, Any]) -> JobReturn:
    """One sweep job inside a Ray worker: Hydra's global state, then the task in its sweep subdir."""
    import ray

    setup_globals()
    Singleton.set_state(singleton_state)
    with open_dict(sweep_config):
        sweep_config.hydra.job.id = ray.get_runtime_context().get_task_id() or f"ray_{idx}"
    HydraConfig.instance().set_config(sweep_config)
    return run_job(hydra_context=hydra_context, task_function=task_function, config=sweep_config,
                   job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir")


def launch(launcher: Launcher, job_overrides: Sequence[Sequence[str]],
           initial_job_idx: int) -> list[JobReturn]:
    """Start (or join) Ray, submit every job, wait for all of them; a failed job fails the sweep."""
    ray = _ray()
    setup_globals()
    assert launcher.config is not None and launcher.hydra_context is not None
    assert launcher.task_function is not None
    configure_log(launcher.config.hydra.hydra_logging, launcher.config.hydra.verbose)
    sweep_dir = Path(str(launcher.config.hydra.sweep.dir))
    sweep_dir.mkdir(parents=True, exist_ok=True)

    init = _options(launcher.init)
    if ray.is_initialized():
        log.info("Ray is already initialised; using it")
    else:
        log.info("ray.init(%s)", ", ".join(f"{k}={v!r}" for k, v in init.items()))
        ray.init(**init)
    remote = _options(launcher.remote)
    task = ray.remote(**remote)(_run_on_worker) if remote else ray.remote(_run_on_worker)
    log.info("Ray is launching %d jobs (%s each), sweep output dir: %s", len(job_overrides),
             remote or "Ray's defaults", sweep_dir)

    singleton_state = Singleton.get_state()
    refs, labels = [], []
    for offset, overrides in enumerate(job_overrides):
        idx = initial_job_idx + offset
        labels.append(f"#{idx} : {' '.join(filter_overrides(overrides))}")
        log.info("\t%s", labels[-1])
        # Composed here, in the driver, so resolved values such as ${now:...} match across jobs.
        sweep_config = launcher.hydra_context.config_loader.load_sweep_config(
            launcher.config, list(overrides))
        with open_dict(sweep_config):
            sweep_config.hydra.job.num = idx
        refs.append(task.remote(idx, sweep_config, launcher.hydra_context, launcher.task_function,
                                singleton_state))

    returns: list[JobReturn] = []
    failures: list[str] = []
    for label, ref in zip(labels, refs, strict=True):
        try:  # wait for every job, so one crash does not hide the others' results
            returns.append(ray.get(ref))
        except Exception as exc:  # a worker that died, or a task Ray could not run
            failures.append(f"{label}: {type(exc).__name__}: {exc}")
    if failures:
        raise RuntimeError("Ray could not run these sweep jobs:\n" + "\n".join(failures))
    return returns
