"""``hydra/launcher=ray``: each job of a ``-m`` sweep is one Ray task (see ``conf/hydra/launcher/ray.yaml``).

The project's own launcher rather than ``hydra-ray-launcher``: every release of that plugin requires
``cloudpickle<3`` (the project's joblib needs ``>=3``) and ``boto3`` (whose botocore needs
``python-dateutil<3``, the project pins 4), so it cannot be installed beside the project's pins.
Ray itself is imported only when a sweep starts, so Hydra's plugin scan works without it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hydra.core.utils import JobReturn
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


class RayLauncher(Launcher):
    """Launch sweep jobs as Ray tasks: ``ray.init(**init)`` once, ``ray.remote(**remote)`` per job."""

    def __init__(self, init: DictConfig | dict[str, Any] | None = None,
                 remote: DictConfig | dict[str, Any] | None = None) -> None:
        self.init = init or {}
        self.remote = remote or {}
        self.config: DictConfig | None = None
        self.task_function: TaskFunction | None = None
        self.hydra_context: HydraContext | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        """Keep what ``launch`` needs (Hydra calls this once per sweep)."""
        self.config = config
        self.task_function = task_function
        self.hydra_context = hydra_context

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        """Run one Ray task per override list; returns their JobReturns in order."""
        from hydra_plugins.rdd_ray_launcher import _core

        return _core.launch(self, job_overrides, initial_job_idx)
