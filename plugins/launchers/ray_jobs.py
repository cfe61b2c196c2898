"""A Hydra sweep's jobs as Ray tasks: what `RayLauncher.launch` does.

The launching process composes every job's config (as Hydra's own launchers do), starts or
joins Ray, and submits one task per job; each task runs Hydra's ``run_job`` in a Ray worker,
so the job's callbacks (the study records of `visphy_core.study`) and its visphy run happen
there. A worker runs the job in the launching process's working directory (relative paths such
as the default ``VISPHY_HOME=visphy-out`` mean the same folder everywhere: on a cluster it must
be a path every node sees) with the launching process's ``forward_env`` variables.

A job that exits (visphy reports bad input as one line and exit status 2) does not take its
Ray worker down: the exit comes back as `JobExited`, every other job still finishes, and the
sweep then exits with that status, as it would under Hydra's basic launcher.
"""

from __future__ import annotations

import fnmatch
import logging
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from omegaconf import OmegaConf, open_dict

from visphy_plugins.launchers.ray_config import make_discoverable

log = logging.getLogger(__name__)

#: Set per job by the study callback in the job's own process: never forwarded.
JOB_SCOPED = ("VISPHY_STUDY_JOB",)

make_discoverable()  # a Ray worker unpickles the launcher class with Hydra's plugin state


class JobExited(Exception):
    """A job called ``sys.exit(code)``; raised in the Ray worker instead of exiting it."""

    def __init__(self, code: Any):
        super().__init__(f"the job exited with status {code}")
        self.code = code


def forwarded_env(patterns: Sequence[str], environ: Mapping[str, str] | None = None
                  ) -> dict[str, str]:
    """The variables of ``environ`` (default: this process's) whose names match a pattern."""
    environ = os.environ if environ is None else environ
    return {name: value for name, value in sorted(environ.items())
            if name not in JOB_SCOPED
            and any(fnmatch.fnmatchcase(name, str(p)) for p in patterns)}


def start_ray(init: dict[str, Any], env: dict[str, str]) -> None:
    """``ray.init(**init)`` unless Ray is already initialised in this process, with ``env`` in
    the job-wide ``runtime_env`` (merged under any ``runtime_env.env_vars`` of ``init``)."""
    try:
        import ray
    except ImportError:
        raise ImportError("hydra/launcher=ray_local and hydra/launcher=ray need Ray: "
                          "pip install 'visphy[distributed]'") from None
    if ray.is_initialized():
        return
    kwargs = dict(init)
    runtime_env = dict(kwargs.pop("runtime_env", None) or {})
    env_vars = {**env, **(runtime_env.get("env_vars") or {})}
    if env_vars:
        runtime_env["env_vars"] = env_vars
    address = kwargs.get("address")
    log.info(f"Ray launcher: joining the Ray cluster at {address}" if address
             else "Ray launcher: starting a local Ray cluster")
    ray.init(**kwargs, runtime_env=runtime_env or None)


def run_job_remote(hydra_context: Any, sweep_config: Any, task_function: Any,
                   singleton_state: dict, launch_cwd: str) -> JobReturn:
    """One job, in a Ray worker (processes are reused between tasks: the working directory
    is put back afterwards, and Hydra's global state is set afresh for every job)."""
    import ray

    setup_globals()
    Singleton.set_state(singleton_state)
    with open_dict(sweep_config):
        sweep_config.hydra.job.id = ray.get_runtime_context().get_task_id()
    HydraConfig.instance().set_config(sweep_config)
    previous = os.getcwd()
    try:
        os.chdir(launch_cwd)
    except OSError as exc:
        raise RuntimeError(f"job {sweep_config.hydra.job.num}: the launching directory "
                           f"{launch_cwd} is not usable on this Ray node ({exc.strerror}): "
                           "launch from a path every node sees") from None
    try:
        return run_job(hydra_context=hydra_context, task_function=task_function,
                       config=sweep_config, job_dir_key="hydra.sweep.dir",
                       job_subdir_key="hydra.sweep.subdir")
    except SystemExit as exc:
        raise JobExited(exc.code) from None
    finally:
        os.chdir(previous)


def launch(launcher: Any, job_overrides: Sequence[Sequence[str]],
           initial_job_idx: int) -> list[JobReturn]:
    """Submit every job, wait for all of them, return their results in job order."""
    import ray

    setup_globals()
    config = launcher.config
    configure_log(config.hydra.hydra_logging, config.hydra.verbose)
    sweep_dir = Path(str(config.hydra.sweep.dir))
    sweep_dir.mkdir(parents=True, exist_ok=True)
    init = OmegaConf.to_container(launcher.init, resolve=True) or {}
    remote = OmegaConf.to_container(launcher.remote, resolve=True) or {}
    start_ray(init, forwarded_env(list(launcher.forward_env or [])))
    task = ray.remote(**remote)(run_job_remote) if remote else ray.remote(run_job_remote)
    log.info(f"Ray launcher: {len(job_overrides)} jobs, sweep output dir: {sweep_dir}")
    cwd = str(config.hydra.runtime.cwd)
    refs = []
    for idx, overrides in enumerate(job_overrides, start=initial_job_idx):
        log.info(f"\t#{idx} : {' '.join(filter_overrides(overrides))}")
        sweep_config = launcher.hydra_context.config_loader.load_sweep_config(
            config, list(overrides))
        with open_dict(sweep_config):
            sweep_config.hydra.job.num = idx
        refs.append(task.remote(launcher.hydra_context, sweep_config, launcher.task_function,
                                Singleton.get_state(), cwd))
    results, exit_code = [], None
    for ref in refs:
        try:
            results.append(ray.get(ref))
        except JobExited as exc:
            exit_code = exc.code if exit_code is None else exit_code
    if exit_code is not None:
        raise SystemExit(exit_code)
    return results
