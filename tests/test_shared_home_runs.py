"""Runs that share a home: started at once on one fresh home with the real sqlite MLflow store,
every run completes with its rows and its MLflow run, and the home works afterwards; a store
that fails is one line and a finished run, logged later with ``visphy track``.

The small version of benchmarks/concurrent_home.py (which the closing notes run in full: eight
runs and a parallel study, five times)."""

from __future__ import annotations

import json
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import FAST_METRICS, REPO

sys.path.insert(0, str(REPO / "benchmarks"))

from concurrent_home import check_home, run_jobs, same_rows  # noqa: E402

pytestmark = [pytest.mark.browser, pytest.mark.timeout(900)]

COMMON = ("dataset=mini", "dataset.limit=1", "run.progress=false", *FAST_METRICS)
JOBS = [("model=oracle", "engine=threejs"), ("model=static", "engine=threejs"),
        ("model=oracle", "engine=threejs")]


def _home(tmp_path: Path, mini_root: Path) -> Path:
    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


def test_three_runs_at_once_then_a_fourth_on_one_fresh_home(tmp_path, mini_root):
    home = _home(tmp_path, mini_root)
    together = run_jobs(home, JOBS, COMMON)
    after = run_jobs(home, JOBS[:1], COMMON)
    assert check_home(home, [*together, *after], n_scenes=1, expected_mlflow_runs=4) == []
    (first,), (twin,), (fourth,) = (j.run_dirs for j in (together[0], together[2], after[0]))
    assert len({first, twin, fourth}) == 3  # a live run is never resumed by its twin
    assert same_rows(first, twin) is None and same_rows(first, fourth) is None
    (static,) = together[1].run_dirs  # a baseline's clips are its own, no model's successes
    lines = together[1].out.splitlines()
    assert any(ln.startswith("baseline clips made 1/1") for ln in lines)
    assert not any(ln.startswith("model success") for ln in lines)
    assert "baseline clips made (no model" in (static / "report" / "index.html").read_text()
    assert (home / "mlflow.db.lock").is_file()
    with sqlite3.connect(home / "mlflow.db") as con:  # MLflow 3's UI opens on the runs list
        kinds = con.execute("select value from experiment_tags where key = "
                            "'mlflow.experimentKind'").fetchall()
    assert kinds == [("custom_model_development",)]


def _cli(home: Path, *args: str) -> subprocess.CompletedProcess:
    import os

    return subprocess.run([sys.executable, "-m", "visphy_core", *args], cwd=REPO,
                          env=dict(os.environ, VISPHY_HOME=str(home)), capture_output=True,
                          text=True, timeout=600)


def test_a_damaged_store_is_one_line_and_the_run_is_logged_later(tmp_path, mini_root):
    """``mlflow.db`` full of garbage: the run finishes (exit 0, its rows, summary and report
    written) and ends with one line naming the store, the fix and ``visphy track``; once the
    file is moved aside, that command logs the run (metrics, tags, tables) and the summary
    records the MLflow run."""
    home = _home(tmp_path, mini_root)
    (home / "mlflow.db").write_bytes(b"this is not a database\n" * 64)
    done = _cli(home, *COMMON, "model=oracle", "engine=threejs")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stdout + done.stderr
    lines = [ln for ln in done.stderr.splitlines() if ln.startswith("MLflow tracking failed")]
    assert len(lines) == 1, done.stderr[-3000:]
    (run_dir,) = (home / "runs").iterdir()
    line = lines[0]
    assert str(home / "mlflow.db") in line and "mv " in line
    assert line.endswith(f"log it with: visphy track {run_dir}")
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["tracking_failed"] == line
    assert "mlflow" not in summary and (run_dir / "report" / "index.html").is_file()

    (home / "mlflow.db").rename(home / "mlflow.db.damaged")
    logged = _cli(home, "track", str(run_dir))
    assert logged.returncode == 0, logged.stderr[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert "tracking_failed" not in summary and summary["mlflow"]["status"] == "FINISHED"
    with sqlite3.connect(home / "mlflow.db") as con:
        ((run_id, status, name),) = con.execute("select run_uuid, status, name from runs")
        tags = dict(con.execute("select key, value from tags where run_uuid = ?", (run_id,)))
        metrics = {k for (k,) in con.execute("select key from metrics where run_uuid = ?",
                                             (run_id,))}
    assert run_id == summary["mlflow"]["run_id"] and status == "FINISHED"
    assert name == "oracle · threejs · mini" and tags["visphy.run_dir"] == str(run_dir)
    assert tags["visphy.logged_later"] == "true"
    assert {"psnr", "n_scenes", "model_success_rate"} <= metrics
    again = _cli(home, "track", str(run_dir))
    assert again.returncode == 0 and "already logged" in again.stdout
