"""Entry point of the harness: ``python run.py [group=option ...]``, ``python run.py -m ...`` for sweeps.

Thin on purpose: Hydra composes the config, ``experiments.run.pipeline.run`` does the work and returns
its summary; the main metric (average success, or mIoU for decomposition-only runs) is returned so
sweepers can use it. Bad input (a config value, an unwritable output folder) is one line and exit
status 2; Ctrl-C and SIGTERM are one line after the cleanups, exit 130 and 143.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

import experiments.config.schemas  # noqa: F401  (registers the typed schema `base_config`)
from experiments.run.interrupts import run_stoppable
from rdd.errors import InputError

log = logging.getLogger("run")
CHECKOUT = str(Path(__file__).resolve().parent)


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> float | None:
    """Run one configuration and return its main metric."""
    from experiments.run.pipeline import run

    try:
        summary = run(cfg)
    except InputError as exc:
        # Bad input (a config value, a data file): one line saying what to fix.
        log.debug("traceback of the failure", exc_info=True)
        log.error("error: %s", exc)
        raise SystemExit(2) from None
    except Exception as exc:
        # One line on the terminal; the traceback goes to the run's log file only (DEBUG).
        out = _output_dir()
        log.debug("traceback of the failure", exc_info=True)
        log.error("run failed: %s: %s", type(exc).__name__, exc)
        log.error("details: %s/run.log", out)
        raise SystemExit(1) from None
    log.info("output directory: %s", summary.get("output_dir"))
    return summary.get("main_metric")


# Launchers of the `cluster` extra, and the module each needs.
CLUSTER_LAUNCHERS = {"slurm": "hydra_plugins.hydra_submitit_launcher",
                     "slurm_local": "hydra_plugins.hydra_submitit_launcher", "ray": "ray"}


def check_launcher(argv: list[str]) -> None:
    """Exit with the install line when ``hydra/launcher=...`` names a launcher whose extra is missing."""
    from hydra_plugins.rdd_ray_launcher import INSTALL_LINE

    for arg in argv:
        name = arg.partition("hydra/launcher=")[2] if arg.lstrip("+").startswith("hydra/launcher=") else ""
        module = CLUSTER_LAUNCHERS.get(name)
        if module is not None and importlib.util.find_spec(module) is None:
            sys.exit(f"hydra/launcher={name} needs the cluster extra ({module} is missing): {INSTALL_LINE}")


def export_checkout() -> None:
    """Put this checkout on ``PYTHONPATH`` for the processes a run starts.

    The harness is not installed (``pip install .`` installs only ``rdd``): this script's folder is
    on its own path, and this makes it the path of its sweep jobs too (joblib workers, Slurm jobs
    through submitit, a Ray cluster started here), wherever the command was started.
    """
    paths = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    if CHECKOUT not in paths:
        os.environ["PYTHONPATH"] = os.pathsep.join([*paths, CHECKOUT])


def _output_dir() -> str:
    from hydra.core.hydra_config import HydraConfig

    try:
        return HydraConfig.get().runtime.output_dir
    except ValueError:
        return "?"


if __name__ == "__main__":
    if "--help" in sys.argv[1:] or "-h" in sys.argv[1:]:
        from experiments.config.run_help import help_text

        print(help_text())
        sys.exit(0)
    check_launcher(sys.argv[1:])
    export_checkout()
    # Ctrl-C and SIGTERM: one line after the cleanups (locks, temporary folders), exit 130 / 143.
    sys.exit(run_stoppable(main))
