"""The Ray launcher as Hydra sees it (``hydra/launcher=ray_local`` or ``ray``): one Ray task per
sweep point. Importing this module must stay cheap (Hydra imports every plugin at start-up):
Ray is imported when a sweep is launched, by `visphy_plugins.launchers.ray_jobs`."""

from __future__ import annotations

from typing import Any, Optional, Sequence

from hydra.core.utils import JobReturn
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


class RayLauncher(Launcher):
    """Runs each job of a multirun as a Ray task, on a local Ray cluster started for the sweep
    (``init.address: null``) or on an existing one (``init.address: auto`` or ``host:port``)."""

    def __init__(self, init: Any, remote: Any, forward_env: Any) -> None:
        self.init = init
        self.remote = remote
        self.forward_env = forward_env
        self.config: Optional[DictConfig] = None
        self.hydra_context: Optional[HydraContext] = None
        self.task_function: Optional[TaskFunction] = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        self.config = config
        self.hydra_context = hydra_context
        self.task_function = task_function

    def launch(self, job_overrides: Sequence[Sequence[str]],
               initial_job_idx: int) -> Sequence[JobReturn]:
        from visphy_plugins.launchers.ray_jobs import launch

        return launch(self, job_overrides, initial_job_idx)
