"""The main command end to end on the mini set, as a user runs it (slow: real Chromium, MLflow)."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pandas as pd
import pytest

from conftest import run_cli

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def _summary(home: Path) -> dict:
    runs = sorted((home / "runs").iterdir())
    return json.loads((runs[-1] / "summary.json").read_text())


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory, mini_root):
    import shutil

    home = tmp_path_factory.mktemp("e2e")
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    first = run_cli("engine=threejs", "model=oracle", "dataset=mini", home=home)
    s1 = _summary(home)
    second = run_cli("engine=threejs", "model=oracle", "dataset=mini", home=home)
    s2 = _summary(home)
    return home, (first, s1), (second, s2)


def test_oracle_reaches_the_pipeline_ceiling(two_runs):
    _, (proc, summary), _ = two_runs
    assert summary["n_scenes"] >= 3 and summary["model_success"] == summary["n_scenes"]
    assert summary["metrics"]["psnr"]["mean_model_success"] >= 30.0
    assert summary["metrics"]["ssim"]["mean_model_success"] >= 0.97
    assert "psnr" in proc.stdout and "model success" in proc.stdout


def test_run_directory_has_every_artifact(two_runs):
    home, (_, summary), _ = two_runs
    run_dir = Path(summary["run_dir"])
    for name in ("config.yaml", "manifest.json", "results.parquet", "results.jsonl",
                 "summary.json"):
        assert (run_dir / name).is_file(), name
    table = pd.read_parquet(run_dir / "results.parquet")
    assert len(table) == summary["n_scenes"]
    assert (table["score_psnr"] >= 30).all()
    scene_dir = run_dir / "scenes" / table["scene_id"].iloc[0]
    for name in ("prompt.json", "response.txt", "analysis.txt", "spec.json", "program.html",
                 "render.log", "video.mp4", "frames_meta.json", "scores.json"):
        assert (scene_dir / name).is_file(), name


def test_second_run_renders_nothing_and_scores_the_same(two_runs):
    _, (_, s1), (proc, s2) = two_runs
    assert s2["cache"]["render"]["misses"] == 0
    assert s2["cache"]["render"]["hits"] == s2["n_scenes"]
    assert s2["renders_done"] == 0
    assert s1["metrics"] == s2["metrics"]
    assert f"renders {s2['n_scenes']} hit / 0 rendered" in proc.stdout


def test_mlflow_store_holds_both_runs(two_runs):
    home, (_, s1), _ = two_runs
    db = home / "mlflow.db"
    assert db.is_file()
    with sqlite3.connect(db) as con:
        runs = con.execute("select name, status from runs").fetchall()
        metrics = dict(con.execute(
            "select key, value from latest_metrics where run_uuid = "
            "(select run_uuid from runs order by start_time limit 1)").fetchall())
    assert len(runs) == 2 and {status for _, status in runs} == {"FINISHED"}
    assert abs(metrics["psnr"] - s1["metrics"]["psnr"]["mean_model_success"]) < 1e-9
    artifacts = list((home / "mlartifacts").rglob("summary.json"))
    assert len(artifacts) == 2
