"""MLflow tracking as a lifecycle-hook plugin: one MLflow run per visphy run.

Default store: ``sqlite:///<paths.root>/mlflow.db`` with the explicit artifact root
``<paths.root>/mlartifacts`` (MLflow 3 refuses the plain file store). See the run with
``mlflow ui --backend-store-uri sqlite:///visphy-out/mlflow.db``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from visphy_core.hookspecs import hookimpl

_ACTIVE: dict[int, Any] = {}
#: visphy run status (``summary["status"]``) → MLflow run status. An interrupted run (SIGINT,
#: SIGTERM) ends KILLED, a run that raised ends FAILED: never left RUNNING.
_MLFLOW_STATUS = {"finished": "FINISHED", "interrupted": "KILLED", "failed": "FAILED",
                  "cost_cap": "KILLED"}


def tracking_uris(cfg, root: Path) -> tuple[str, str]:
    """(tracking URI, artifact root URI) from the ``tracking`` config group."""
    uri = cfg.tracking.uri or f"sqlite:///{(root / 'mlflow.db').resolve()}"
    artifacts = cfg.tracking.artifact_root or str((root / "mlartifacts").resolve())
    if "://" not in artifacts:
        artifacts = Path(artifacts).resolve().as_uri()
    return uri, artifacts


def flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(flatten(v, f"{prefix}{k}."))
    else:
        out[prefix[:-1]] = d
    return out


def _enabled(run) -> bool:
    return run.cfg.tracking.backend == "mlflow"


@hookimpl
def visphy_run_start(run):
    if not _enabled(run):
        return
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    from mlflow.tracking import MlflowClient

    logging.getLogger("alembic").setLevel(logging.WARNING)
    logging.getLogger("mlflow").setLevel(logging.WARNING)
    uri, artifacts = tracking_uris(run.cfg, run.root)
    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name(run.cfg.tracking.experiment)
    exp_id = exp.experiment_id if exp else client.create_experiment(
        run.cfg.tracking.experiment, artifact_location=artifacts)
    params = flatten(OmegaConf.to_container(run.cfg, resolve=True))
    mlrun = client.create_run(exp_id, run_name=run.run_dir.name,
                              tags={"visphy.run_dir": str(run.run_dir),
                                    "visphy.model": run.model_name,
                                    "visphy.engine": run.engine_name})
    for key, value in sorted(params.items()):
        client.log_param(mlrun.info.run_id, key[:250], str(value)[:6000])
    _ACTIVE[id(run)] = (client, mlrun.info.run_id)
    previous = (run.extra.get("resumed_from") or {}).get("mlflow") or {}
    if previous.get("run_id"):  # the killed process's run: resumed here, so no longer RUNNING
        client.set_tag(mlrun.info.run_id, "visphy.resumed_from", previous["run_id"])
        try:
            if client.get_run(previous["run_id"]).info.status == "RUNNING":
                client.set_terminated(previous["run_id"], status="KILLED")
        except Exception as exc:  # noqa: BLE001 - another store, or the run was deleted
            logging.getLogger("visphy.tracking").warning(
                "could not close the interrupted MLflow run %s: %s", previous["run_id"], exc)
    run.extra["mlflow"] = {"tracking_uri": uri, "run_id": mlrun.info.run_id,
                           "experiment_id": exp_id}


@hookimpl
def visphy_scene_done(run, scene, result):
    active = _ACTIVE.get(id(run))
    if active is None:
        return
    client, run_id = active
    step = len(run.results)
    for name, value in result.scores.items():
        if value is not None:
            client.log_metric(run_id, f"scene/{name}", value, step=step)


@hookimpl
def visphy_run_end(run, summary):
    active = _ACTIVE.pop(id(run), None)
    if active is None:
        return
    client, run_id = active
    for name, m in summary["metrics"].items():
        if m["mean_model_success"] is not None:
            client.log_metric(run_id, name, m["mean_model_success"])
        if m["mean_with_fallbacks"] is not None:
            client.log_metric(run_id, f"{name}_with_fallbacks", m["mean_with_fallbacks"])
    for key in ("model_success_rate", "model_success_rate_evaluable", "system_success_rate",
                "fallbacks", "n_scenes", "n_evaluable"):
        if summary.get(key) is not None:
            client.log_metric(run_id, key, float(summary[key]))
    for stage, totals in (summary.get("usage") or {}).items():
        for field in ("calls", "cache_hits", "errors", "input_tokens", "output_tokens",
                      "cached_input_tokens", "reasoning_tokens", "cost_usd",
                      "cost_usd_incl_cached"):
            client.log_metric(run_id, f"usage.{stage}.{field}", float(totals.get(field) or 0))
    for key, judge in (summary.get("judges") or {}).items():
        client.log_metric(run_id, f"judge.{key}.n_valid", float(judge["n_valid"]))
        client.log_metric(run_id, f"judge.{key}.n_invalid", float(judge["n_invalid"]))
    if summary.get("prompt_versions"):
        client.set_tag(run_id, "visphy.prompt_version", ",".join(summary["prompt_versions"]))
    for name in ("config.yaml", "manifest.json", "summary.json", "results.parquet",
                 "results.jsonl", "calls.jsonl"):
        path = run.run_dir / name
        if path.is_file():
            client.log_artifact(run_id, str(path))
    status = _MLFLOW_STATUS.get(summary.get("status", "finished"), "FAILED")
    client.set_terminated(run_id, status=status)
    summary["mlflow"] = dict(run.extra["mlflow"], status=status)
