"""The tracking plugin's lifecycle: one MLflow run per visphy run (a child of its study's
parent run), opened at the run's start and logged and closed at its end; a store that fails is
one line for the end of the run, never the run's end; `log_finished_run` logs a finished run
directory after the fact (``visphy track``)."""

from __future__ import annotations

import functools
import logging
import shlex
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from visphy_core.api.hookspecs import hookimpl
from visphy_core.results.layout import RUN_FILES, VIDEO
from visphy_core.results.run_dir import RunDir
from visphy_core.tracking.shards import adopt_shard_runs
from visphy_core.tracking.store import (
    log_metrics,
    log_params,
    mlflow_command,
    open_store,
    sqlite_file,
    store_lock,
    tracking_uris,
)
from visphy_core.tracking.values import (
    headline_clip,
    run_params,
    scene_table,
    summary_metrics,
    table_column,
)

log = logging.getLogger("visphy.tracking")


#: The MLflow run (client, run id) of each visphy run in progress, by ``id(run)``.
_ACTIVE: dict[int, Any] = {}
#: Why tracking a run in progress failed at its start (one line for its end), by ``id(run)``.
_FAILED: dict[int, str] = {}
#: visphy run status (``summary["status"]``) → MLflow run status. An interrupted run (SIGINT,
#: SIGTERM) ends KILLED, a run that raised ends FAILED: never left RUNNING.
_MLFLOW_STATUS = {"finished": "FINISHED", "interrupted": "KILLED", "failed": "FAILED",
                  "cost_cap": "KILLED"}
#: The per-scene table (one row per scene, a column per score) and a study's comparison table,
#: logged with `MlflowClient.log_table`: the UI shows them as tables.
SCENE_TABLE, STUDY_TABLE = "scenes.json", "comparison.json"


@functools.lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit of the visphy checkout this code runs from (None for an installed wheel, or
    when git is missing)."""
    repo = Path(__file__).resolve().parents[2]
    if not (repo / ".git").exists():
        return None
    try:
        out = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit if out.returncode == 0 and len(commit) == 40 else None


def source_tags() -> dict[str, str]:
    commit = git_commit()
    return {"mlflow.source.git.commit": commit, "visphy.git_commit": commit} if commit else {}


def benchmark_version(run) -> str:
    """The dataset config's name and the benchmark build the scenes come from (a generated
    build's folder names its generator version and seed: ``visphybench-v3-seed0``)."""
    builds = run.datasets
    return f"{run.cfg.dataset.name}:{','.join(builds)}" if builds else str(run.cfg.dataset.name)


def _run_tags(run) -> dict[str, str]:
    rescored = run.rescored_from or {}  # `score`: the run this one re-scores
    return {"visphy.run_dir": str(run.run_dir), "visphy.model": run.model_name,
            "visphy.engine": run.engine_name, "visphy.benchmark_version": benchmark_version(run),
            "visphy.dataset": str(OmegaConf.select(run.cfg, "dataset.name", default="")),
            **source_tags(),
            **({"visphy.rescored_from": rescored["run_dir"]} if rescored else {}),
            **({"visphy.rescored_from_run_id": rescored["mlflow_run_id"]}
               if rescored.get("mlflow_run_id") else {})}


def start_study_run(cfg, study: str, run_name: str, tags: dict[str, str],
                    params: dict[str, Any]) -> dict[str, str]:
    """Open a study's parent run; returns what its jobs need to become its children."""
    root = Path(cfg.paths.root).resolve()
    with store_lock(tracking_uris(cfg, root)[0]):
        client, uri, exp_id = open_store(cfg, root)
        mlrun = client.create_run(exp_id, run_name=run_name,
                                  tags={"visphy.study": study, "visphy.role": "study", **tags,
                                        **source_tags()})
        log_params(client, mlrun.info.run_id, params)
    return {"tracking_uri": uri, "run_id": mlrun.info.run_id, "experiment_id": exp_id,
            "experiment": str(cfg.tracking.experiment)}


def end_study_run(parent: dict[str, str], status: str, metrics: dict[str, float],
                  artifacts: list[tuple[Path, str | None]], tags: dict[str, str],
                  table: list[dict] | None = None) -> None:
    """Log the study's metrics, its comparison table (``table``, one row per job, as
    ``comparison.json``, `table_column` names) and outputs (files or folders, each with its
    artifact path) to the parent run and close it with MLflow status ``status``."""
    from mlflow.tracking import MlflowClient

    with store_lock(parent["tracking_uri"]):
        client = MlflowClient(tracking_uri=parent["tracking_uri"])
        run_id = parent["run_id"]
        log_metrics(client, run_id, metrics)
        for key, value in tags.items():
            client.set_tag(run_id, key, value)
        if table:
            import pandas as pd

            client.log_table(run_id, pd.DataFrame(table).rename(columns=table_column),
                             STUDY_TABLE)
        for path, artifact_path in artifacts:
            if path.is_dir():
                client.log_artifacts(run_id, str(path), artifact_path)
            elif path.is_file():
                client.log_artifact(run_id, str(path), artifact_path)
        client.set_terminated(run_id, status=status)


def _study_parent(uri: str) -> tuple[dict, dict] | None:
    """(job record, parent run) when this run is a job of a study tracked in the same store."""
    from visphy_core.results.study_records import current_job

    found = current_job()
    if found is None:
        return None
    job, study = found
    parent = study.get("parent")
    if parent and parent.get("tracking_uri") != uri:  # e.g. a node resolved another VISPHY_HOME
        log.warning("study %s tracks to %s but this job to %s: its MLflow run is not a child of "
                    "the study's run (give every job the same tracking.uri or VISPHY_HOME)",
                    study.get("name", ""), parent.get("tracking_uri"), uri)
    if not parent or parent.get("tracking_uri") != uri:
        return None
    return job, dict(parent, study=study.get("name", ""), sweep=list(study.get("sweep") or {}))


def run_display_name(cfg) -> str:
    """``model · engine · dataset`` (``dataset:split`` when the split is not the dataset's
    name): what the MLflow runs list shows of a run (its folder name stays a tag)."""
    dataset = str(OmegaConf.select(cfg, "dataset.name", default="?"))
    split = OmegaConf.select(cfg, "dataset.split", default=None)
    if split not in (None, "", dataset):
        dataset = f"{dataset}:{split}"
    return f"{cfg.model.name} · {cfg.engine.name} · {dataset}"


def _enabled(run) -> bool:
    return run.cfg.tracking.backend == "mlflow"


@hookimpl
def visphy_run_start(run):
    """Open the run's MLflow run. A store that fails (locked, damaged, unreachable) is one
    warning and a note for the end of the run: the run itself goes on untracked."""
    if not _enabled(run):
        return
    try:
        _start(run)
    except Exception as exc:  # noqa: BLE001 - tracking is a record of the run, not the run
        _FAILED[id(run)] = _problem(run, exc)
        log.warning("%s", _FAILED[id(run)])
        _close_failed(_ACTIVE.pop(id(run), None))


def _close_failed(active) -> None:
    """Mark an MLflow run whose logging failed FAILED (never left RUNNING), if the store lets
    us."""
    if active is None:
        return
    client, run_id = active
    try:
        client.set_terminated(run_id, status="FAILED")
    except Exception:  # noqa: BLE001 - the store that just failed may fail again
        pass


def _start(run) -> None:
    with store_lock(tracking_uris(run.cfg, run.root)[0]):
        _start_locked(run)


def _start_locked(run) -> None:
    client, uri, exp_id = open_store(run.cfg, run.root)
    tags, run_name = _run_tags(run), run_display_name(run.cfg)
    if run.rescored_from:  # `score`: its own run, beside the one it re-scores
        run_name += " · re-scored"
    study = _study_parent(uri)
    if study is not None:
        job, parent = study
        exp_id = parent["experiment_id"]
        tags.update({"mlflow.parentRunId": parent["run_id"], "visphy.study": parent["study"],
                     "visphy.job": str(job.get("num", ""))})
        run_name = job.get("label") or run_name
    mlrun = client.create_run(exp_id, run_name=run_name, tags=tags)
    _ACTIVE[id(run)] = (client, mlrun.info.run_id)
    log_params(client, mlrun.info.run_id,
               run_params(run.cfg, study[1].get("sweep", ()) if study else ()))
    previous = run.resumed_from.get("mlflow") or {}
    if previous.get("run_id"):  # the killed process's run: resumed here, so no longer RUNNING
        client.set_tag(mlrun.info.run_id, "visphy.resumed_from", previous["run_id"])
        try:
            if client.get_run(previous["run_id"]).info.status == "RUNNING":
                client.set_terminated(previous["run_id"], status="KILLED")
        except Exception as exc:  # noqa: BLE001 - another store, or the run was deleted
            log.warning("could not close the interrupted MLflow run %s: %s",
                        previous["run_id"], exc)
    run.tracking["mlflow"] = {"tracking_uri": uri, "run_id": mlrun.info.run_id,
                           "experiment_id": exp_id}


def _problem(run, exc: BaseException) -> str:
    """One line: which store failed and why, and how to log the finished run later."""
    try:
        uri = tracking_uris(run.cfg, run.root)[0]
    except Exception:  # noqa: BLE001 - a config without the tracking group
        uri = "the tracking store"
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    cut = text.find(" [SQL:")  # SQLAlchemy appends the statement and a help link
    text = text[:cut] if cut > 0 else text
    if len(text) > 240:
        text = text[:239] + "…"
    db = sqlite_file(uri)
    damaged = any(w in text.lower() for w in ("not a database", "malformed", "file is encrypted",
                                               "no such table", "can't locate revision"))
    fix = (f"the store file is damaged: move it aside (mv {shlex.quote(str(db))} "
           f"{shlex.quote(str(db))}.damaged), then " if db is not None and damaged else "")
    return (f"MLflow tracking failed ({uri}: {text}); the run's results are complete: "
            f"{fix}log it with: {track_command(run.run_dir)}")


def track_command(run_dir: Path) -> str:
    """The command that logs a finished run directory to MLflow (`log_finished_run`)."""
    return f"visphy track {shlex.quote(str(run_dir))}"


def run_report(run_dir: Path) -> Path | None:
    """The run's HTML report folder, written now (`visphy_core.report.write_run_report`) so the
    MLflow run gets the report of the run as it ends; None when the report module is missing or
    fails (a warning: tracking goes on)."""
    try:
        from visphy_core.report import write_run_report
    except ImportError:
        return None
    try:
        return Path(write_run_report(run_dir)).parent
    except Exception as exc:  # noqa: BLE001 - a report is never worth a failed run
        log.warning("the HTML report of %s for MLflow failed: %s: %s", run_dir,
                    type(exc).__name__, exc)
        return None


def _log_run_files(client, run_id: str, run, summary: dict, report: Path | None) -> None:
    if run.results:
        client.log_table(run_id, scene_table(run.results, list(summary.get("metrics") or {})),
                         SCENE_TABLE)
    run_files = RunDir(run.run_dir)
    for path in run_files.present(RUN_FILES):
        client.log_artifact(run_id, str(path))
    if report is not None:
        client.log_artifacts(run_id, str(report), "report")
    if run.cfg.tracking.get("log_videos"):
        for video in sorted(run_files.scenes.glob(f"*/{VIDEO}")):
            client.log_artifact(run_id, str(video), f"videos/{video.parent.name}")


@hookimpl
def visphy_run_end(run, summary):
    """Log the run's metrics and files and close its MLflow run. A failure here (or at the
    start) is recorded as ``summary["tracking_failed"]`` (one line, printed at the end of the
    run) and the MLflow run, if one was opened, is marked FAILED: the run's own files are
    already written and the run ends as it would have."""
    active = _ACTIVE.pop(id(run), None)
    failed = _FAILED.pop(id(run), None)
    if failed:
        summary["tracking_failed"] = failed
    if active is None:
        return
    client, run_id = active
    try:
        _end(client, run_id, run, summary)
    except Exception as exc:  # noqa: BLE001 - tracking is a record of the run, not the run
        summary["tracking_failed"] = _problem(run, exc)
        summary.pop("mlflow", None)
        log.warning("%s", summary["tracking_failed"])
        _close_failed(active)


def _end(client, run_id: str, run, summary: dict) -> None:
    report = run_report(run.run_dir)  # written before the store is locked: no store access
    with store_lock(run.tracking["mlflow"]["tracking_uri"]):
        _end_locked(client, run_id, run, summary, report)


def _end_locked(client, run_id: str, run, summary: dict, report: Path | None) -> None:
    log_metrics(client, run_id, summary_metrics(summary, headline_clip(run.cfg)))
    if summary.get("prompt_versions"):
        client.set_tag(run_id, "visphy.prompt_version", ",".join(summary["prompt_versions"]))
    _log_run_files(client, run_id, run, summary, report)
    linked = []
    if run.merged_from:
        linked = adopt_shard_runs(client, run_id, run.tracking["mlflow"]["tracking_uri"],
                                  run.merged_from)
    status = _MLFLOW_STATUS.get(summary.get("status", "finished"), "FAILED")
    client.set_terminated(run_id, status=status)
    summary["mlflow"] = dict(run.tracking["mlflow"], status=status)
    if linked:
        summary["mlflow"]["shard_runs"] = linked
    run.where_to_look.append(f"MLflow: {mlflow_command(run.tracking['mlflow']['tracking_uri'])}")


@dataclass
class FinishedRun:
    """A finished run directory in the shape the hooks read (the fields of
    `visphy_core.api.run_context.RunContext` that tracking uses), for logging it after the
    fact."""

    cfg: Any
    run_dir: Path
    root: Path
    model_name: str
    engine_name: str
    results: list
    datasets: list[str]
    tracking: dict[str, dict[str, Any]] = field(default_factory=dict)
    resumed_from: dict[str, dict[str, Any]] = field(default_factory=dict)
    rescored_from: dict[str, Any] | None = None
    merged_from: list[dict[str, Any]] = field(default_factory=list)
    where_to_look: list[str] = field(default_factory=list)


def log_finished_run(data, uri: str | None = None, experiment: str | None = None) -> dict:
    """Log a finished run directory (``data``: `visphy_core.results.load.RunData`) to MLflow as
    its run would have at its end: the same tags, params, metrics, tables and files, in the
    store its config names (or ``uri`` / ``experiment``). Returns the summary's ``mlflow``
    entry (tracking URI, run id, experiment id, status). Raises whatever the store raises."""
    cfg = OmegaConf.create(data.config)
    OmegaConf.set_struct(cfg, False)
    cfg.tracking = OmegaConf.merge(
        {"backend": "mlflow", "uri": None, "artifact_root": None, "experiment": "visphy",
         "log_videos": False}, cfg.get("tracking") or {},
        {k: v for k, v in (("uri", uri), ("experiment", experiment)) if v})
    cfg.tracking.backend = "mlflow"
    root = Path(OmegaConf.select(cfg, "paths.root", default=None) or data.run_dir.parents[1])
    run = FinishedRun(cfg=cfg, run_dir=data.run_dir, root=root, model_name=data.model,
                      engine_name=data.engine, results=data.results,
                      datasets=sorted({str(d) for d in data.manifest.get("datasets") or [] if d}),
                      merged_from=list(data.manifest.get("merged_from") or []))
    summary = dict(data.summary)
    _start(run)
    client, run_id = _ACTIVE.pop(id(run))
    client.set_tag(run_id, "visphy.logged_later", "true")
    try:
        _end(client, run_id, run, summary)
    except BaseException:
        client.set_terminated(run_id, status="FAILED")
        raise
    return summary["mlflow"]
