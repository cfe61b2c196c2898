"""MLflow tracking as a lifecycle-hook plugin: one MLflow run per visphy run, and one parent run
per study (a multirun) with the jobs' runs as its children.

Default store: ``sqlite:///<paths.root>/mlflow.db`` with the explicit artifact root
``<paths.root>/mlartifacts`` (MLflow 3 refuses the plain file store); ``tracking.uri`` may name
a tracking server (``http://host:port``), which then decides where artifacts go unless
``tracking.artifact_root`` says. See the runs with
``mlflow ui --backend-store-uri sqlite:///visphy-out/mlflow.db`` (docs/results/mlflow.md).

A run logs, at its end:

* metrics, the ones to look at first: ``headline`` (the summary's headline mean over every
  scored scene) with ``headline.lo``/``headline.hi`` (its 95% bootstrap interval) and
  ``headline.n``; ``family.<family>`` per metric family (`family_means`); success rates and
  counts; then each score column's mean over model successes (``<column>``) and over every
  scored scene (``<column>_with_fallbacks``, for the metrics' own and normalised columns);
  usage, judge counts and stage seconds. No per-scene steps: the per-scene values are the
  table artifact ``scenes.json``;
* params: only those that tell runs apart (`KEY_PARAMS`, the swept keys of a study); the whole
  resolved config is the artifact ``config.yaml``;
* artifacts: ``scenes.json`` (`MlflowClient.log_table`: one row per scene, a column per score
  named as the score with ``_`` for ``.``, shown as a table by the UI), the run's files
  (config, manifest, summary, the per-scene table as Parquet and JSONL, the call ledger), the
  HTML report under ``report/`` when one was written, the clips under ``videos/`` with
  ``tracking.log_videos=true``.

System tags: ``visphy.run_dir``, ``visphy.model``, ``visphy.engine``, ``visphy.dataset``,
``visphy.prompt_version``, ``visphy.benchmark_version``, ``visphy.study``,
``mlflow.source.git.commit`` and ``visphy.git_commit`` (when visphy runs from a git checkout).
A study's parent run gets the comparison table ``comparison.json`` (`study_row` per job) from
`visphy_core.study.finish`.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import shlex
import subprocess
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from omegaconf import OmegaConf

from visphy_core.api.hookspecs import hookimpl
from visphy_core.infra.locks import exclusive, lock_path
from visphy_core.results.columns import NORM_PREFIX

log = logging.getLogger("visphy.tracking")
_ACTIVE: dict[int, Any] = {}
#: visphy run status (``summary["status"]``) → MLflow run status. An interrupted run (SIGINT,
#: SIGTERM) ends KILLED, a run that raised ends FAILED: never left RUNNING.
_MLFLOW_STATUS = {"finished": "FINISHED", "interrupted": "KILLED", "failed": "FAILED",
                  "cost_cap": "KILLED"}
#: The run's own files logged as artifacts (when present).
RUN_FILES = ("config.yaml", "manifest.json", "summary.json", "results.parquet", "results.jsonl",
             "calls.jsonl")
#: The per-scene table (one row per scene, a column per score) and a study's comparison table,
#: logged with `MlflowClient.log_table`: the UI shows them as tables.
SCENE_TABLE, STUDY_TABLE = "scenes.json", "comparison.json"
#: The config values logged as params (when set): what tells runs apart. The whole resolved
#: config is the artifact config.yaml; a study's swept keys are params too.
KEY_PARAMS = ("model.name", "model.model_id", "model.style", "model.reasoning_effort",
              "model.thinking_budget", "model.temperature", "engine.name", "dataset.name",
              "dataset.split", "dataset.limit", "dataset.seed", "metrics.variance_norm",
              "metrics.spec_track", "prompt.frames", "prompt.detection",
              "prompt.forecast_only", "prompt.timed", "run.seed", "run.retry", "run.fallback",
              "reference.source")
#: Summary counts logged as metrics.
SUMMARY_COUNTS = ("model_success_rate", "model_success_rate_evaluable", "system_success_rate",
                  "model_success", "system_success", "repaired", "fallbacks", "n_scenes",
                  "n_evaluable")
USAGE_FIELDS = ("calls", "cache_hits", "errors", "input_tokens", "output_tokens",
                "cached_input_tokens", "reasoning_tokens", "cost_usd", "cost_usd_incl_cached")


# ------------------------------------------------------------------------------ store


def tracking_uris(cfg, root: Path) -> tuple[str, str | None]:
    """(tracking URI, artifact root URI) from the ``tracking`` config group. A tracking server
    (http/https) chooses the artifact location itself unless ``tracking.artifact_root`` is set
    (artifact root None)."""
    uri = cfg.tracking.uri or f"sqlite:///{(root / 'mlflow.db').resolve()}"
    artifacts = cfg.tracking.artifact_root
    if not artifacts and uri.split("://", 1)[0] in ("http", "https"):
        return uri, None
    artifacts = artifacts or str((root / "mlartifacts").resolve())
    if "://" not in artifacts:
        artifacts = Path(artifacts).resolve().as_uri()
    return uri, artifacts


def sqlite_file(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` tracking URI (None for a server or another
    database)."""
    if not uri.startswith("sqlite:///"):
        return None
    path = uri[len("sqlite:///"):]
    return Path(path if path.startswith("/") else f"./{path}")


#: File systems on which SQLite's write-ahead log is unsafe (no shared memory across hosts).
NETWORK_FS = ("nfs", "nfs4", "cifs", "smb3", "smbfs", "fuse.sshfs", "9p", "afs", "lustre",
              "gpfs", "beegfs", "ceph", "glusterfs")


def file_system_type(path: Path) -> str:
    """The type of the file system holding ``path`` (``/proc/mounts``; "" when unknown)."""
    try:
        mounts = Path("/proc/mounts").read_text().splitlines()
    except OSError:
        return ""
    target, best, kind = str(path.resolve()), -1, ""
    for line in mounts:
        fields = line.split()
        if len(fields) < 3:
            continue
        point = fields[1].replace("\\040", " ")
        if (target == point or target.startswith(point.rstrip("/") + "/")) \
                and len(point) > best:
            best, kind = len(point), fields[2]
    return kind


def _prepare_sqlite(db: Path) -> None:
    """Once the schema exists: the write-ahead log (readers never block the writer; set in
    the file, so once is enough), except on a network file system where it is unsafe."""
    import sqlite3

    if file_system_type(db.parent).lower() in NETWORK_FS:
        return
    with sqlite3.connect(db, timeout=30) as conn:
        if conn.execute("PRAGMA journal_mode").fetchone()[0].lower() != "wal":
            conn.execute("PRAGMA journal_mode=WAL")


def open_store(cfg, root: Path):
    """(MlflowClient, tracking URI, experiment id) of ``tracking.experiment``, created on first
    use with the configured artifact root.

    Any number of processes may open one sqlite store at once: its schema is created (MLflow
    runs its migrations on first use) and the experiment looked up or created under an
    exclusive lock on ``mlflow.db.lock`` beside the file (`visphy_core.infra.locks`), so two
    processes never migrate the same file at once; the file is then switched to SQLite's
    write-ahead log (readers never wait for the writer). Every write of a run goes through
    `store_lock` too. A tracking server serialises its writers itself."""
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    from mlflow.tracking import MlflowClient

    logging.getLogger("alembic").setLevel(logging.WARNING)
    logging.getLogger("mlflow").setLevel(logging.WARNING)
    uri, artifacts = tracking_uris(cfg, root)
    db = sqlite_file(uri)
    with store_lock(uri):
        client = MlflowClient(tracking_uri=uri)
        name = cfg.tracking.experiment
        exp = client.get_experiment_by_name(name)  # the store (and its schema) is made here
        if db is not None:
            _prepare_sqlite(db)
        exp_id = exp.experiment_id if exp else _create_experiment(client, name, artifacts)
    return client, uri, exp_id


def store_lock(uri: str):
    """Exclusive use of a sqlite tracking store across processes (a no-op for a server). Each
    process writes a run's records under it in one go: SQLite lets one writer in at a time,
    and a transaction that read before another process wrote fails at once ("database is
    locked") whatever the busy timeout, so writers take turns here instead."""
    db = sqlite_file(uri)
    return exclusive(lock_path(db), f"the MLflow store {db}") if db else nullcontext()


def _create_experiment(client, name: str, artifacts: str | None) -> str:
    """Create the experiment; when another process (through a tracking server) created it
    first, use theirs."""
    from mlflow.exceptions import MlflowException

    try:
        return client.create_experiment(name, artifact_location=artifacts)
    except MlflowException:
        exp = client.get_experiment_by_name(name)
        if exp is None:
            raise
        return exp.experiment_id


def flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(flatten(v, f"{prefix}{k}."))
    else:
        out[prefix[:-1]] = d
    return out


def log_params(client, run_id: str, params: dict[str, Any]) -> None:
    """Params in batches (one request per 100 over a tracking server); MLflow's length limits."""
    from mlflow.entities import Param

    from visphy_core.infra.secrets import public_config

    client.log_batch(run_id, params=[Param(key[:250], str(public_config(str(value)))[:6000])
                                     for key, value in sorted(params.items())])


def log_metrics(client, run_id: str, metrics: dict[str, float], step: int = 0) -> None:
    from mlflow.entities import Metric

    now = int(time.time() * 1000)
    client.log_batch(run_id, metrics=[Metric(key, float(value), now, step)
                                      for key, value in metrics.items() if value is not None])


# ------------------------------------------------------------------------------ tags


@functools.lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit of the visphy checkout this code runs from (None for an installed wheel, or
    when git is missing)."""
    repo = Path(__file__).resolve().parents[1]
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
    builds = sorted({s.dataset for s in run.scenes if s.dataset})
    return f"{run.cfg.dataset.name}:{','.join(builds)}" if builds else str(run.cfg.dataset.name)


def _run_tags(run) -> dict[str, str]:
    rescored = run.extra.get("rescored_from") or {}  # `score`: the run this one re-scores
    return {"visphy.run_dir": str(run.run_dir), "visphy.model": run.model_name,
            "visphy.engine": run.engine_name, "visphy.benchmark_version": benchmark_version(run),
            "visphy.dataset": str(OmegaConf.select(run.cfg, "dataset.name", default="")),
            **source_tags(),
            **({"visphy.rescored_from": rescored["run_dir"]} if rescored else {}),
            **({"visphy.rescored_from_run_id": rescored["mlflow_run_id"]}
               if rescored.get("mlflow_run_id") else {})}


# ------------------------------------------------------------------------------ studies


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


#: A study's comparison table: of `headline_metrics`, these (and every ``family.*``).
STUDY_COLUMNS = ("headline", "headline.lo", "headline.hi", "model_success_rate",
                 "system_success_rate", "n_scenes", "fallbacks")


def study_row(summary: dict, clip: tuple[float, float] = (-1.0, 1.0)) -> dict[str, float]:
    """A job's numbers in its study's comparison table: the headline with its interval, the
    family means, success rates and counts (as its own run logs them)."""
    values = headline_metrics(summary, clip)
    return {k: v for k, v in values.items() if k in STUDY_COLUMNS or k.startswith("family.")}


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


# ------------------------------------------------------------------------------ hooks


def mlflow_executable() -> str:
    """``mlflow`` when that is this environment's MLflow on the path, else its full path (the
    venv not activated), so the printed command works as printed."""
    import shutil
    import sys

    here = Path(sys.executable).with_name("mlflow")
    found = shutil.which("mlflow")
    if found and (not here.exists() or Path(found).resolve() == here.resolve()):
        return "mlflow"
    return str(here) if here.exists() else "mlflow"


def mlflow_command(tracking_uri: str) -> str:
    """How to look at a tracking store: the exact ``mlflow ui`` command for a local store, the
    server's address for a remote one."""
    if tracking_uri.split("://", 1)[0].lower() in ("http", "https", "databricks"):
        return f"open {tracking_uri} (the tracking server holding this run)"
    return f"{shlex.quote(mlflow_executable())} ui --backend-store-uri {shlex.quote(tracking_uri)}"


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
        _ACTIVE.pop(id(run), None)
        run.extra["tracking_failed"] = _problem(run, exc)
        log.warning("%s", run.extra["tracking_failed"])


def _start(run) -> None:
    with store_lock(tracking_uris(run.cfg, run.root)[0]):
        _start_locked(run)


def _start_locked(run) -> None:
    client, uri, exp_id = open_store(run.cfg, run.root)
    tags, run_name = _run_tags(run), run_display_name(run.cfg)
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
    previous = (run.extra.get("resumed_from") or {}).get("mlflow") or {}
    if previous.get("run_id"):  # the killed process's run: resumed here, so no longer RUNNING
        client.set_tag(mlrun.info.run_id, "visphy.resumed_from", previous["run_id"])
        try:
            if client.get_run(previous["run_id"]).info.status == "RUNNING":
                client.set_terminated(previous["run_id"], status="KILLED")
        except Exception as exc:  # noqa: BLE001 - another store, or the run was deleted
            log.warning("could not close the interrupted MLflow run %s: %s",
                        previous["run_id"], exc)
    run.extra["mlflow"] = {"tracking_uri": uri, "run_id": mlrun.info.run_id,
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


def run_params(cfg, swept=()) -> dict[str, Any]:
    """The params of a run: `KEY_PARAMS` and a study's swept keys (those with a value, a group
    such as ``model`` by its ``.name``), the judges (``judge``, ``none`` without one) and the
    metric suite chosen (``metrics.suite``: ``default``, ``fast``… when Hydra composed it)."""
    out: dict[str, Any] = {}
    for key in (*KEY_PARAMS, *(k.lstrip("+~") for k in swept if "/" not in k)):
        value = OmegaConf.select(cfg, key, default=None)
        if OmegaConf.is_list(value):
            value = ",".join(str(v) for v in value)
        elif OmegaConf.is_dict(value):
            value = value.get("name")
        if isinstance(value, Enum):  # a structured config's choice: its name, as written
            value = value.name
        if value is not None:
            out[key] = value
    out["judge"] = ",".join(sorted(OmegaConf.select(cfg, "judge", default=None) or {})) or "none"
    try:
        from hydra.core.hydra_config import HydraConfig

        out["metrics.suite"] = str(HydraConfig.get().runtime.choices["metrics"])
    except Exception:  # noqa: BLE001 - not composed by Hydra (merge, score): no suite name
        pass
    return out


def headline_clip(cfg) -> tuple[float, float]:
    """``metrics.headline.clip``: the range each normalised component is clipped to."""
    clip = OmegaConf.select(cfg, "metrics.headline.clip", default=None) or (-1.0, 1.0)
    return float(clip[0]), float(clip[1])


def family_means(summary: dict, clip: tuple[float, float] = (-1.0, 1.0)) -> dict[str, float]:
    """``family.<family>``: per metric family (``metric_info``), the mean of its metrics'
    variance-normalised means over every scored scene (``norm.<metric>``: the still clip 0, the
    ground truth's twin 1, higher is better for every metric and direction), each clipped to
    the headline's ``clip`` first, as the headline clips its components. A family none of
    whose metrics has a normalised mean (text metrics, a dataset without specs,
    ``metrics.variance_norm=false``) has no entry: raw means in different units do not
    average."""
    info = summary.get("metric_info") or {}
    groups: dict[str, list[float]] = {}
    for name, m in (summary.get("metrics") or {}).items():
        family = (info.get(name[len(NORM_PREFIX):]) or {}).get("family")
        mean = m.get("mean_with_fallbacks")
        if name.startswith(NORM_PREFIX) and family and mean is not None and math.isfinite(mean):
            groups.setdefault(str(family), []).append(min(max(float(mean), clip[0]), clip[1]))
    return {f"family.{f}": sum(v) / len(v) for f, v in sorted(groups.items())}


def headline_metrics(summary: dict, clip: tuple[float, float] = (-1.0, 1.0)
                     ) -> dict[str, float]:
    """The few metrics to look at first: ``headline`` (+ ``.lo``, ``.hi``, ``.n``), the
    family means, success rates and counts."""
    out: dict[str, float] = {}
    head = summary.get("headline") or {}
    if head.get("mean") is not None:
        out["headline"] = float(head["mean"])
        out["headline.n"] = float(head.get("n") or 0)
        if head.get("ci"):
            out["headline.lo"], out["headline.hi"] = (float(v) for v in head["ci"])
    out.update(family_means(summary, clip))
    for key in SUMMARY_COUNTS:
        if summary.get(key) is not None:
            out[key] = float(summary[key])
    return out


def summary_metrics(summary: dict, clip: tuple[float, float] = (-1.0, 1.0)
                    ) -> dict[str, float]:
    """Every metric of a run: `headline_metrics`; each score column's mean over model
    successes (``<name>``) and, for the metrics' own columns (``psnr``, the headline's, a
    judge's) and their normalised ones (``norm.psnr``), over all scenes with fallbacks scored
    (``<name>_with_fallbacks``; the counts are in ``scenes.json`` and ``summary.json``); usage
    per stage; judge verdict counts; stage seconds."""
    out = headline_metrics(summary, clip)
    for name, m in summary["metrics"].items():
        if m.get("mean_model_success") is not None:
            out[name] = m["mean_model_success"]
        own = "." not in name.removeprefix(NORM_PREFIX)
        if own and m.get("mean_with_fallbacks") is not None:
            out[f"{name}_with_fallbacks"] = m["mean_with_fallbacks"]
    for stage, totals in (summary.get("usage") or {}).items():
        for name in USAGE_FIELDS:
            out[f"usage.{stage}.{name}"] = float(totals.get(name) or 0)
    for key, judge in (summary.get("judges") or {}).items():
        out[f"judge.{key}.n_valid"] = float(judge["n_valid"])
        out[f"judge.{key}.n_invalid"] = float(judge["n_invalid"])
    for stage, totals in (summary.get("stage_seconds") or {}).items():
        out[f"seconds.{stage}"] = float(totals.get("total") or 0)
        if totals.get("mean") is not None:
            out[f"seconds.{stage}.per_scene"] = float(totals["mean"])
    return out


def table_column(name: str) -> str:
    """A column name of a logged table: dots become underscores (``psnr.aligned`` →
    ``psnr_aligned``, ``family.pixel`` → ``family_pixel``): MLflow's table view reads a dot as
    a nested field and shows such a column empty."""
    return name.replace(".", "_")


def scene_table(results: list, columns: list[str]):
    """The per-scene table: ``scene_id``, ``outcome``, then a column per score (in the
    summary's order, the headline first; `table_column` names); an undefined score is
    empty."""
    import pandas as pd

    rows = [{"scene_id": r.scene_id, "outcome": r.outcome,
             **{table_column(c): r.scores.get(c) for c in columns}} for r in results]
    return pd.DataFrame(rows, columns=["scene_id", "outcome", *map(table_column, columns)])


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
    for name in RUN_FILES:
        path = run.run_dir / name
        if path.is_file():
            client.log_artifact(run_id, str(path))
    if report is not None:
        client.log_artifacts(run_id, str(report), "report")
    if run.cfg.tracking.get("log_videos"):
        for video in sorted(run.run_dir.glob("scenes/*/video.mp4")):
            client.log_artifact(run_id, str(video), f"videos/{video.parent.name}")


@hookimpl
def visphy_run_end(run, summary):
    """Log the run's metrics and files and close its MLflow run. A failure here (or at the
    start) is recorded as ``summary["tracking_failed"]`` (one line, printed at the end of the
    run) and the MLflow run, if one was opened, is marked FAILED: the run's own files are
    already written and the run ends as it would have."""
    active = _ACTIVE.pop(id(run), None)
    if run.extra.get("tracking_failed"):
        summary["tracking_failed"] = run.extra["tracking_failed"]
    if active is None:
        return
    client, run_id = active
    try:
        _end(client, run_id, run, summary)
    except Exception as exc:  # noqa: BLE001 - tracking is a record of the run, not the run
        summary["tracking_failed"] = _problem(run, exc)
        summary.pop("mlflow", None)
        log.warning("%s", summary["tracking_failed"])
        try:
            client.set_terminated(run_id, status="FAILED")
        except Exception:  # noqa: BLE001 - the store that just failed may fail again
            pass


def _end(client, run_id: str, run, summary: dict) -> None:
    report = run_report(run.run_dir)  # written before the store is locked: no store access
    with store_lock(run.extra["mlflow"]["tracking_uri"]):
        _end_locked(client, run_id, run, summary, report)


def _end_locked(client, run_id: str, run, summary: dict, report: Path | None) -> None:
    log_metrics(client, run_id, summary_metrics(summary, headline_clip(run.cfg)))
    if summary.get("prompt_versions"):
        client.set_tag(run_id, "visphy.prompt_version", ",".join(summary["prompt_versions"]))
    _log_run_files(client, run_id, run, summary, report)
    status = _MLFLOW_STATUS.get(summary.get("status", "finished"), "FAILED")
    client.set_terminated(run_id, status=status)
    summary["mlflow"] = dict(run.extra["mlflow"], status=status)


# ------------------------------------------------------------------------------ later


@dataclass
class FinishedRun:
    """A finished run directory in the shape the hooks read (`RunContext`'s fields that
    tracking uses), for logging it after the fact."""

    cfg: Any
    run_dir: Path
    root: Path
    model_name: str
    engine_name: str
    results: list
    scenes: list
    extra: dict = field(default_factory=dict)


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
                      scenes=[SimpleNamespace(dataset=d)
                              for d in data.manifest.get("datasets") or []])
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
