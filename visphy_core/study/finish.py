"""The end of a study: collect the jobs' runs, analyse them, write the report, close the parent.

Everything lands in the study's folder (the sweep dir, ``<paths.root>/studies/<study>-<time>/``
for the shipped experiments)::

    study.json            the study: name, overrides, swept keys, parent MLflow run, status
    jobs/<n>/visphy_job.json  one record per job: overrides, status, run directory
    analysis/             the study analysis (`visphy_core.analysis.study.analyse`): tables,
                          figures, matrices
    report/index.html     the study report (`visphy_core.report.write_study_report`)
    study_summary.json    the jobs, their outcomes and where every output is

and the same outputs are logged to the parent MLflow run as artifacts, with the comparison table
``comparison.json`` (`comparison_rows`: one row per job, its swept values, headline, family means
and success rates), the metric ``best.headline`` and the tag ``visphy.best_job`` (the job with
the highest headline). A study whose jobs did not all finish is analysed over the ones that
did; its parent run ends FAILED (a job raised) or KILLED (a job never returned: interrupted).
"""

from __future__ import annotations

import datetime as dt
import sys
import traceback
from pathlib import Path
from typing import Any

from visphy_core.results import study_records as records
from visphy_core.results.layout import STUDY_SUMMARY
from visphy_core.results.run_dir import RunDir


def _status(jobs: list[dict], ended_early: bool) -> str:
    if any(j.get("status") in (records.RUNNING, records.ABORTED) for j in jobs):
        return "KILLED"
    if ended_early or any(j.get("status") == records.FAILED for j in jobs):
        return "FAILED"
    return "FINISHED"


def analyse_runs(run_dirs: list[Path], study_dir: Path, study: str) -> dict[str, Any]:
    """Run the study analysis and the study report over the jobs' run directories; returns
    where the outputs are (``analysis``, ``report``) and, per part that could not run, why."""
    out: dict[str, Any] = {"problems": []}
    markdown, tables, figures = "", {}, {}
    try:
        from visphy_core.analysis.load import load_runs
        from visphy_core.analysis.study import analyse
    except ImportError as exc:
        out["problems"].append(f"study analysis not available ({exc}): the jobs' runs are "
                               f"listed in {STUDY_SUMMARY}")
    else:
        from visphy_core.analysis.printing import print_study

        outputs = analyse(load_runs(run_dirs), study_dir / "analysis",
                          study=None if study == "multirun" else study)
        print_study(outputs, study_dir / "analysis")
        tables, figures = outputs.tables, outputs.figures
        markdown = outputs.markdown or ""
        out["analysis"] = str(study_dir / "analysis")
        out["files"] = [str(p) for p in (outputs.files or [])]
    try:
        from visphy_core.report import write_study_report
    except ImportError as exc:
        out["problems"].append(f"study report not available ({exc})")
    else:
        report = write_study_report(run_dirs, study_dir / "report", title=f"Study: {study}",
                                    tables=tables, figures=figures, markdown=markdown)
        out["report"] = str(report)
    return out


def swept_values(job: dict, keys) -> dict[str, str]:
    """The job's value of each swept key, from its overrides (``model=<name>`` → model)."""
    values = {}
    for override in job.get("overrides") or []:
        key, _, value = str(override).partition("=")
        if key.lstrip("+~") in {k.lstrip("+~") for k in keys}:
            values[key.lstrip("+~")] = value
    return values


def comparison_rows(jobs: list[dict], sweep) -> list[dict[str, Any]]:
    """The study's comparison table: per job its number, label, swept values, status, MLflow run
    and, when it completed, its headline with interval, family means and success rates
    (`visphy_core.tracking.study_row`)."""
    from visphy_core.tracking import headline_clip, study_row

    rows = []
    for job in jobs:
        row: dict[str, Any] = {"job": job.get("num"), "label": job.get("label"),
                               **swept_values(job, sweep or {}),
                               "status": job.get("run_status") or job.get("status"),
                               "mlflow_run_id": job.get("mlflow_run_id")}
        run_dir = Path(job["run_dir"]) if job.get("run_dir") else None
        run = RunDir(run_dir) if run_dir else None
        if job.get("status") == records.COMPLETED and run and run.summary_file.is_file():
            try:
                summary = run.read_summary()
            except (OSError, ValueError):
                summary = {}
            clip = headline_clip(run.read_config()) if run.config_file.is_file() \
                else (-1.0, 1.0)
            row.update(study_row(summary, clip))
        rows.append(row)
    return rows


def _best(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    scored = [r for r in rows if r.get("headline") is not None]
    return max(scored, key=lambda r: r["headline"]) if scored else None


def _mlflow_hint(parent: dict | None) -> str | None:
    if not parent:
        return None
    uri = parent["tracking_uri"]
    if uri.startswith(("http://", "https://")):
        return (f"MLflow: {uri.rstrip('/')}/#/experiments/{parent['experiment_id']}/runs/"
                f"{parent['run_id']}")
    from visphy_core.tracking import mlflow_command

    return (f"MLflow: parent run {parent['run_id']} in experiment '{parent['experiment']}'; "
            f"view with: {mlflow_command(uri)}")


def finish_study(sweep_dir: Path, *, ended_early: bool = False) -> dict[str, Any] | None:
    """Analyse the study in ``sweep_dir``, log its outputs to the parent run and close it.
    Idempotent: a study already finished is left alone."""
    sweep_dir = Path(sweep_dir)
    study = records.read_study(sweep_dir)
    if study is None or study.get("status") != "running":
        return study
    records.update_study(sweep_dir, status="finishing")
    name = study.get("name", "multirun")
    jobs = records.read_jobs(sweep_dir)
    status = _status(jobs, ended_early)
    for job in jobs:
        if job.get("status") == records.RUNNING:  # the sweep is over: it never returned
            job.update(records.write_job(Path(job["job_dir"]), status=records.ABORTED,
                                         error="the sweep ended while this job ran "
                                               "(interrupted, or an error stopped the sweep)"))
    run_dirs = [Path(j["run_dir"]) for j in jobs
                if j.get("status") == records.COMPLETED and j.get("run_dir")]
    outputs: dict[str, Any] = {"problems": []}
    if run_dirs and status != "KILLED":
        try:
            outputs = analyse_runs(run_dirs, sweep_dir, name)
        except Exception as exc:  # noqa: BLE001 - the jobs' results stay; say what broke
            traceback.print_exc(file=sys.stderr)
            outputs["problems"].append(f"study analysis failed: {type(exc).__name__}: {exc}")
            status = "FAILED"
    summary = {"study": name, "status": status, "sweep_dir": str(sweep_dir),
               "overrides": study.get("overrides"), "sweep": study.get("sweep"),
               "parent": study.get("parent"),
               "n_jobs": len(jobs), "n_completed": len(run_dirs),
               "jobs": [{k: j.get(k) for k in ("num", "label", "status", "run_dir",
                                                "run_status", "mlflow_run_id", "error")}
                        for j in jobs],
               **outputs}
    parent = study.get("parent")
    rows: list[dict[str, Any]] = []
    if parent:
        try:
            rows = comparison_rows(jobs, study.get("sweep"))
        except Exception as exc:  # noqa: BLE001 - the parent run is closed all the same
            summary["problems"].append(f"comparison table failed: {type(exc).__name__}: {exc}")
    records.write_json(sweep_dir / STUDY_SUMMARY, summary)
    if parent:
        from visphy_core.tracking import end_study_run

        best = _best(rows)
        end_study_run(parent, status,
                      metrics={"n_jobs": len(jobs), "n_completed": len(run_dirs),
                               "n_failed": len(jobs) - len(run_dirs),
                               **({"best.headline": best["headline"]} if best else {})},
                      artifacts=[(sweep_dir / "analysis", "analysis"),
                                 (sweep_dir / "report", "report"),
                                 (sweep_dir / STUDY_SUMMARY, None),
                                 (sweep_dir / records.STUDY_FILE, None)],
                      tags={"visphy.study_status": status.lower(),
                            **({"visphy.best_job": str(best["label"])} if best else {})},
                      table=rows)
    records.update_study(sweep_dir, status=status.lower(),
                         ended=dt.datetime.now().isoformat(timespec="seconds"))
    _print_outcome(summary, parent)
    return summary


def _print_outcome(summary: dict[str, Any], parent: dict | None) -> None:
    lines = [f"study {summary['study']}: {summary['n_completed']}/{summary['n_jobs']} jobs "
             f"completed ({summary['status'].lower()})",
             f"  folder: {summary['sweep_dir']}"]
    if summary.get("report"):
        lines.append(f"  report: {summary['report']}")
    lines += [f"  note: {p}" for p in summary.get("problems", [])]
    hint = _mlflow_hint(parent)
    if hint:
        lines.append(f"  {hint}")
    print("\n".join(lines), flush=True)
