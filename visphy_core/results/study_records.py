"""The files that tie a study together: one study file in the sweep dir, one record per job.

Jobs may run in this process, in joblib workers or on SLURM nodes, so nothing is passed in
memory: the study file (``<sweep dir>/study.json``) holds the study's name and its parent MLflow
run, and each job writes ``<job dir>/visphy_job.json`` (started, then completed or failed, with
its run directory). While a job runs, ``$VISPHY_STUDY_JOB`` names its job dir, which is how the
tracking plugin finds the parent run of the run it opens (`current_job`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from visphy_core.results.layout import JOB_FILE, STUDY_FILE

#: Set in a job's process while the job runs: its Hydra job dir.
JOB_ENV = "VISPHY_STUDY_JOB"

#: Job record statuses. A job still "running" when the sweep ends died with its process (an
#: interrupt, a bad input that stops the whole sweep): the study marks it "aborted".
RUNNING, COMPLETED, FAILED, ABORTED = "running", "completed", "failed", "aborted"


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write atomically (a reader in another process never sees half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=2, default=str) + "\n")
    os.replace(tmp, path)


def read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def study_file(sweep_dir: Path) -> Path:
    return Path(sweep_dir) / STUDY_FILE


def read_study(sweep_dir: Path) -> dict[str, Any] | None:
    return read_json(study_file(sweep_dir))


def update_study(sweep_dir: Path, **fields: Any) -> dict[str, Any]:
    data = read_study(sweep_dir) or {}
    data.update(fields)
    write_json(study_file(sweep_dir), data)
    return data


def write_job(job_dir: Path, **fields: Any) -> dict[str, Any]:
    """Merge ``fields`` into the job's record."""
    path = Path(job_dir) / JOB_FILE
    data = read_json(path) or {}
    data.update(fields)
    write_json(path, data)
    return data


def read_jobs(sweep_dir: Path) -> list[dict[str, Any]]:
    """Every job record under the sweep dir, in job order."""
    records = []
    for path in Path(sweep_dir).rglob(JOB_FILE):
        data = read_json(path)
        if data is not None:
            records.append(dict(data, job_dir=str(path.parent)))
    return sorted(records, key=lambda r: (int(r.get("num", 0)), r["job_dir"]))


def current_job() -> tuple[dict[str, Any], dict[str, Any]] | None:
    """(this job's record, its study) while a study job runs in this process, else None."""
    job_dir = os.environ.get(JOB_ENV)
    if not job_dir:
        return None
    job = read_json(Path(job_dir) / JOB_FILE)
    if job is None or not job.get("sweep_dir"):
        return None
    study = read_study(Path(job["sweep_dir"]))
    return (job, study) if study is not None else None
