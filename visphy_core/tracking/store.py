"""The MLflow tracking store: where it is (``tracking.uri``, else the home's sqlite file), how
processes share it (`store_lock`), opening it (`open_store`) and writing to it in batches, and
the command that shows it (`mlflow_command`)."""

from __future__ import annotations

import logging
import os
import shlex
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any

from visphy_core.infra.locks import exclusive, lock_path

log = logging.getLogger("visphy.tracking")

#: MLflow's usage telemetry stays off unless the user turns it on: its background thread sets
#: and removes an environment variable while the run's threads read the environment (a race
#: that failed a run's tracking with ``KeyError: '_MLFLOW_TELEMETRY_SESSION_ID'`` when eight
#: runs shared a machine), and it would send requests from machines that are often offline.
#: Set before MLflow is first imported (this module is imported when the plugin loads).
os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")


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
        if exp is None or EXPERIMENT_KIND not in (exp.tags or {}):
            client.set_experiment_tag(exp_id, *EXPERIMENT_KIND_TAG)
    return client, uri, exp_id


#: MLflow 3's UI opens an experiment on the tab its kind says: visphy's runs are model
#: development (params, metrics, artifacts), not GenAI traces, so the runs list comes first.
EXPERIMENT_KIND = "mlflow.experimentKind"
EXPERIMENT_KIND_TAG = (EXPERIMENT_KIND, "custom_model_development")


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
