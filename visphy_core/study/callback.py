"""The Hydra callback that makes a multirun a study (enabled in
``conf/hydra/callbacks/visphy_study.yaml``).

* ``on_multirun_start`` (the launching process): open the parent MLflow run and write the study
  file into the sweep dir; register an exit handler so that a sweep that dies (a job raised, a
  Ctrl-C) still closes the parent run and analyses the jobs that finished.
* ``on_job_start`` / ``on_job_end`` (wherever the launcher runs the job): the job record in the
  Hydra job dir, and ``$VISPHY_STUDY_JOB`` while the job runs so that the tracking plugin makes
  the job's MLflow run a child of the parent.
* ``on_multirun_end``: `finish.finish_study` (analysis, report, parent run closed).

The study's name is the experiment's (``experiment=leaderboard``), ``multirun`` without one.
"""

from __future__ import annotations

import atexit
import datetime as dt
import os
import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from visphy_core.results import study_records as records


def study_name(config: DictConfig) -> str:
    choice = OmegaConf.select(config, "hydra.runtime.choices.experiment", default=None)
    return str(choice) if choice else "multirun"


def effective_sweep(config: DictConfig) -> dict[str, str]:
    """What a multirun sweeps, key -> values as written: the experiment's
    ``hydra.sweeper.params``, with a command-line override of the same key in its place (Hydra's
    basic sweeper lets the command line win) and every other command-line sweep added."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = OmegaConf.select(config, "hydra.sweeper.params", default=None) or {}
    sweep = {str(k): str(v) for k, v in params.items()}
    for ov in OverridesParser.create().parse_overrides(list(config.hydra.overrides.task)):
        key = ov.get_key_element()
        if ov.is_sweep_override() or key in sweep:
            sweep[key] = ov.input_line.split("=", 1)[1]
    return sweep


def _multirun(config: DictConfig) -> bool:
    return OmegaConf.select(config, "hydra.mode", default=None) == RunMode.MULTIRUN


def count_jobs(sweep: dict[str, str]) -> int | None:
    """How many jobs the sweep makes (the product of each swept key's number of values), None
    when a value is not one the parser can count."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        parsed = OverridesParser.create().parse_overrides([f"{k}={v}" for k, v in sweep.items()])
        total = 1
        for ov in parsed:
            if ov.is_sweep_override():
                total *= len(list(ov.sweep_string_iterator()))
        return total
    except Exception:  # noqa: BLE001 - a count for a progress line only
        return None


def study_progress_line(sweep_dir: Path, study: dict, num: int, label: str,
                        now: dt.datetime | None = None) -> str:
    """``study leaderboard: job 3/6 (model=<name>) · 2 done, 0 failed · 4 min 10 s elapsed ·
    ETA 8 min 20 s``: where a sweep is, as a job starts (from the job records on disk)."""
    from visphy_core.infra.progress import duration

    jobs = records.read_jobs(sweep_dir)
    done = sum(1 for j in jobs if j.get("status") == records.COMPLETED)
    failed = sum(1 for j in jobs if j.get("status") == records.FAILED)
    total = study.get("n_jobs")
    parts = [f"study {study.get('name', 'multirun')}: job {num + 1}"
             + (f"/{total}" if total else "") + (f" ({label})" if label else ""),
             f"{done} done, {failed} failed"]
    try:
        elapsed = ((now or dt.datetime.now())
                   - dt.datetime.fromisoformat(study["started"])).total_seconds()
    except (KeyError, TypeError, ValueError):
        elapsed = None
    if elapsed is not None:
        parts.append(f"{duration(elapsed)} elapsed")
        finished = done + failed
        if total and finished and total > finished:
            parts.append(f"ETA {duration(elapsed / finished * (total - finished))}")
    return " · ".join(parts)


def _sweep_dir(config: DictConfig) -> Path:
    return Path(str(config.hydra.sweep.dir)).resolve()


def _now() -> str:
    return dt.datetime.now().isoformat(timespec="seconds")


class StudyCallback(Callback):
    """Parent/child MLflow runs, job records and the study analysis for every multirun. Holds
    no state: it is pickled to the launcher's workers, and everything shared is a file."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = _sweep_dir(config)
        sweep_dir.mkdir(parents=True, exist_ok=True)
        study = study_name(config)
        overrides = [str(o) for o in config.hydra.overrides.task]
        sweep = effective_sweep(config)
        parent = None
        if str(OmegaConf.select(config, "tracking.backend", default="none")) == "mlflow":
            from visphy_core.tracking import start_study_run

            parent = start_study_run(
                config, study, run_name=sweep_dir.name,
                tags={"visphy.sweep_dir": str(sweep_dir),
                      "visphy.dataset": str(OmegaConf.select(config, "dataset.name"))},
                params={"study": study, "overrides": " ".join(overrides),
                        **{f"sweep.{k}": v for k, v in sweep.items()}})
        n_jobs = count_jobs(sweep)
        records.write_json(records.study_file(sweep_dir), {
            "name": study, "sweep_dir": str(sweep_dir), "status": "running",
            "started": _now(), "overrides": overrides, "sweep": sweep,
            "parent": parent, "n_jobs": n_jobs})
        print(f"study {study}: {sweep_dir}" + (f" ({n_jobs} jobs)" if n_jobs else ""),
              flush=True)
        atexit.register(_finish_at_exit, sweep_dir)

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        if not _multirun(config):
            return
        sweep_dir = _sweep_dir(config)
        study = records.read_study(sweep_dir) or {}
        keys = set(study.get("sweep") or {})
        overrides = [str(o) for o in config.hydra.overrides.task]
        num = int(config.hydra.job.num)
        label = " ".join(o for o in overrides if o.split("=", 1)[0].lstrip("+~") in keys)
        job_dir = Path(str(config.hydra.runtime.output_dir)).resolve()
        records.write_job(job_dir, num=num, sweep_dir=str(sweep_dir), overrides=overrides,
                          label=label or f"{study.get('name', 'job')} #{num}",
                          status=records.RUNNING, pid=os.getpid(), started=_now())
        os.environ[records.JOB_ENV] = str(job_dir)
        print(study_progress_line(sweep_dir, study, num, label), file=sys.stderr, flush=True)

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        if not _multirun(config):
            return
        from hydra.core.utils import JobStatus

        job_dir = Path(str(config.hydra.runtime.output_dir)).resolve()
        value = getattr(job_return, "_return_value", None)
        fields: dict[str, Any] = {"ended": _now()}
        if job_return.status == JobStatus.COMPLETED:
            summary = value if isinstance(value, dict) else {}
            fields.update(status=records.COMPLETED, run_dir=summary.get("run_dir"),
                          run_status=summary.get("status"),
                          mlflow_run_id=(summary.get("mlflow") or {}).get("run_id"))
        else:
            fields.update(status=records.FAILED, error=f"{type(value).__name__}: {value}")
        records.write_job(job_dir, **fields)
        os.environ.pop(records.JOB_ENV, None)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        from visphy_core.study.finish import finish_study

        finish_study(_sweep_dir(config))


def _finish_at_exit(sweep_dir: Path) -> None:
    """The sweep ended without ``on_multirun_end`` (a job raised, the user interrupted it)."""
    study = records.read_study(sweep_dir)
    if study is None or study.get("status") != "running":
        return
    from visphy_core.study.finish import finish_study

    finish_study(sweep_dir, ended_early=True)
