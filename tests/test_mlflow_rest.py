"""A study tracked on a real ``mlflow server`` (sqlite backend, local artifact store, loopback),
checked only through the server's REST API: the parent run, its children, their params, metrics
(the headline first, no per-scene steps), system tags and artifacts (the per-scene table
``scenes.json``, the Parquet rows, the reports, the study's comparison table and analysis).
The family means need normalised scores (a dataset with specs): tests/test_tracking.py."""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pandas as pd
import pytest

from conftest import REPO, run_cli

pytestmark = pytest.mark.slow
MODELS = ("static", "flow_extrapolate")
SCORES = ("psnr", "ssim", "spatiotemporal_iou_tol")  # the last: a component of the headline


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get(base: str, endpoint: str, **query) -> dict:
    url = f"{base}{endpoint}?{urllib.parse.urlencode(query)}" if query else f"{base}{endpoint}"
    with urllib.request.urlopen(url, timeout=30) as resp:
        return json.loads(resp.read())


def _post(base: str, endpoint: str, body: dict) -> dict:
    req = urllib.request.Request(f"{base}{endpoint}", data=json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as resp:
        return json.loads(resp.read())


def _download(base: str, run: dict, path: str) -> bytes:
    """An artifact's bytes through the server's artifact proxy (mlflow-artifacts:/...)."""
    root = run["info"]["artifact_uri"].removeprefix("mlflow-artifacts:")
    url = f"{base}/api/2.0/mlflow-artifacts/artifacts{root}/{path}"
    with urllib.request.urlopen(url, timeout=30) as resp:
        return resp.read()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """`mlflow server` on a free loopback port; its base URL once /health answers."""
    root = tmp_path_factory.mktemp("mlflow-server")
    port = _free_port()
    mlflow = Path(sys.executable).with_name("mlflow")
    proc = subprocess.Popen(
        [str(mlflow), "server", "--host", "127.0.0.1", "--port", str(port), "--workers", "1",
         "--backend-store-uri", f"sqlite:///{root / 'mlflow.db'}",
         "--artifacts-destination", str(root / "artifacts")],
        stdout=(root / "server.log").open("w"), stderr=subprocess.STDOUT,
        start_new_session=True)  # its own process group: the server and its uvicorn worker
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180
        while True:
            try:
                with urllib.request.urlopen(f"{base}/health", timeout=2) as resp:
                    if resp.status == 200:
                        break
            except OSError:
                pass
            assert proc.poll() is None, (root / "server.log").read_text()[-3000:]
            assert time.monotonic() < deadline, "mlflow server did not answer /health"
            time.sleep(0.3)
        yield base
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:  # uvicorn drains open connections first
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)


@pytest.fixture(scope="module")
def study(server, tmp_path_factory):
    """The baselines study (two pixel-space baselines, two scenes of the tiny fixture dataset)
    tracked on the server; (base URL, the experiment's runs by role, the study folder, the
    finished process)."""
    home = tmp_path_factory.mktemp("home")
    proc = run_cli("-m", "experiment=baselines", f"model={','.join(MODELS)}", "dataset=tiny",
                   "dataset.limit=2", f"metrics.names=[{','.join(SCORES)}]",
                   "metrics.spec_track=false", "metrics.variance_norm=false",
                   f"tracking.uri={server}", "tracking.log_videos=true", "run.progress=false",
                   home=home)
    [folder] = sorted((home / "studies").glob("baselines-*"))
    exp = _get(server, "/api/2.0/mlflow/experiments/get-by-name", experiment_name="visphy")
    runs = _post(server, "/api/2.0/mlflow/runs/search",
                 {"experiment_ids": [exp["experiment"]["experiment_id"]], "max_results": 100})
    by_role: dict[str, list] = {"parent": [], "child": []}
    for run in runs["runs"]:
        run["tags"] = {t["key"]: t["value"] for t in run["data"].get("tags", [])}
        run["params"] = {p["key"]: p["value"] for p in run["data"].get("params", [])}
        run["metrics"] = {m["key"]: m["value"] for m in run["data"].get("metrics", [])}
        by_role["parent" if run["tags"].get("visphy.role") == "study" else "child"].append(run)
    return server, by_role, folder, proc


def _files(base: str, run: dict, path: str = "") -> dict[str, bool]:
    query = {"run_id": run["info"]["run_id"], **({"path": path} if path else {})}
    listing = _get(base, "/api/2.0/mlflow/artifacts/list", **query)
    return {f["path"]: f["is_dir"] for f in listing.get("files", [])}


def _table(base: str, run: dict, path: str) -> pd.DataFrame:
    """A table logged with log_table (JSON, pandas' split orientation), listed in the run's
    ``mlflow.loggedArtifacts`` tag so the UI offers it as a table."""
    assert {"path": path, "type": "table"} in json.loads(run["tags"]["mlflow.loggedArtifacts"])
    return pd.read_json(io.BytesIO(_download(base, run, path)), orient="split")


def test_one_parent_run_and_a_child_per_job(study):
    _, runs, folder, proc = study
    [parent] = runs["parent"]
    assert parent["info"]["status"] == "FINISHED"
    assert parent["info"]["run_name"] == folder.name
    assert parent["tags"]["visphy.study"] == "baselines"
    assert parent["params"]["study"] == "baselines"
    # the command line's model sweep replaced the file's; the file's engine stays
    assert parent["params"]["sweep.model"] == "static,flow_extrapolate"
    assert parent["params"]["sweep.engine"] == "threejs"
    assert len(runs["child"]) == 2
    best = max(runs["child"], key=lambda c: c["metrics"]["headline"])
    assert parent["metrics"] == {"n_jobs": 2.0, "n_completed": 2.0, "n_failed": 0.0,
                                 "best.headline": best["metrics"]["headline"]}
    assert parent["tags"]["visphy.best_job"] == best["info"]["run_name"]
    for child in runs["child"]:
        assert child["tags"]["mlflow.parentRunId"] == parent["info"]["run_id"]
        assert child["info"]["status"] == "FINISHED"
    assert parent["info"]["run_id"] in proc.stdout  # the printed link names the parent run


def test_children_carry_key_params_headline_metrics_and_system_tags(study):
    base, runs, _, _ = study
    assert {c["tags"]["visphy.model"] for c in runs["child"]} == set(MODELS)
    assert any("headline.lo" in c["metrics"] for c in runs["child"])
    for child in runs["child"]:
        tags, params, metrics = child["tags"], child["params"], child["metrics"]
        assert tags["visphy.engine"] == "threejs" and tags["visphy.study"] == "baselines"
        assert tags["visphy.benchmark_version"] == "tiny:visphybench/sub"
        assert tags["visphy.dataset"] == "tiny"
        commit = tags["mlflow.source.git.commit"]
        assert commit == tags["visphy.git_commit"] and len(commit) == 40
        assert subprocess.run(["git", "-C", str(REPO), "merge-base", "--is-ancestor", commit,
                               "HEAD"]).returncode == 0  # this checkout's commit (or HEAD's past)
        assert tags["visphy.prompt_version"]
        assert tags["mlflow.runName"] == f"model={tags['visphy.model']} engine=threejs"
        # the params that tell runs apart (the swept keys among them); the rest: config.yaml
        assert params["model.name"] == params["model"] == tags["visphy.model"]
        assert params["engine"] == params["engine.name"] == "threejs"
        assert params["dataset.name"] == "tiny" and params["dataset.limit"] == "2"
        assert params["judge"] == "none" and len(params) < 30
        assert not [k for k in params if k.startswith(("paths.", "metrics.align", "sandbox."))]
        summary = json.loads(Path(tags["visphy.run_dir"], "summary.json").read_text())
        head = summary["headline"]
        assert metrics["headline"] == pytest.approx(head["mean"])
        assert metrics["headline.n"] == head["n"]
        if head["ci"]:  # two scenes with a headline (a flow extrapolation leaves one undefined)
            assert [metrics["headline.lo"], metrics["headline.hi"]] == pytest.approx(head["ci"])
        else:
            assert "headline.lo" not in metrics and head["n"] == 1
        assert not [k for k in metrics if k.startswith("family.")]  # tiny: no specs, no twins
        psnr = summary["metrics"]["psnr"]
        assert metrics["psnr"] == pytest.approx(psnr["mean_model_success"])
        assert metrics["psnr_with_fallbacks"] == pytest.approx(psnr["mean_with_fallbacks"])
        assert metrics["model_success_rate"] == 1.0 and metrics["n_scenes"] == 2.0
        assert not [k for k in metrics if k.startswith("scene/") or k.endswith("_n")]
        history = _get(base, "/api/2.0/mlflow/metrics/get-history",
                       run_id=child["info"]["run_id"], metric_key="psnr")
        assert len(history["metrics"]) == 1  # one value, no per-scene steps


def test_children_artifacts_hold_the_scene_table_report_and_videos(study):
    base, runs, _, _ = study
    for child in runs["child"]:
        files = _files(base, child)
        for name in ("results.parquet", "summary.json", "config.yaml", "manifest.json",
                     "scenes.json"):
            assert files.get(name) is False, name
        assert files.get("report") is True and "report/index.html" in _files(base, child,
                                                                              "report")
        scenes = sorted(path.split("/")[-1] for path in _files(base, child, "videos"))
        assert len(scenes) == 2
        assert f"videos/{scenes[0]}/video.mp4" in _files(base, child, f"videos/{scenes[0]}")
        rows = pd.read_parquet(io.BytesIO(_download(base, child, "results.parquet")))
        table = _table(base, child, "scenes.json")
        summary = json.loads(_download(base, child, "summary.json"))
        # a row per scene; scene, outcome, then a column per score (the headline first)
        assert sorted(table["scene_id"]) == scenes == sorted(rows["scene_id"])
        # named as the scores, "_" for ".": MLflow's table view reads a dot as a nested field
        assert list(table.columns) == ["scene_id", "outcome",
                                       *(c.replace(".", "_") for c in summary["metrics"])]
        assert list(table.columns)[2] == summary["headline"]["metric"]
        assert set(SCORES) <= set(table.columns) and set(table["outcome"]) == {"ok"}
        assert table["psnr"].tolist() == pytest.approx(rows["score_psnr"].tolist())
        assert table["psnr"].mean() == pytest.approx(child["metrics"]["psnr"])


def test_the_parent_holds_the_comparison_table_study_analysis_and_report(study):
    base, runs, folder, _ = study
    [parent] = runs["parent"]
    files = _files(base, parent)
    assert files.get("analysis") is True and files.get("report") is True
    assert files.get("study_summary.json") is False
    analysis = _files(base, parent, "analysis")
    assert "analysis/leaderboard.csv" in analysis and "analysis/analysis.md" in analysis
    assert "report/index.html" in _files(base, parent, "report")
    board = pd.read_csv(io.BytesIO(_download(base, parent, "analysis/leaderboard.csv")))
    assert len(board) == 2
    summary = json.loads(_download(base, parent, "study_summary.json"))
    assert summary == json.loads((folder / "study_summary.json").read_text())
    assert {j["mlflow_run_id"] for j in summary["jobs"]} == \
        {c["info"]["run_id"] for c in runs["child"]}
    # one row per job: its swept values, outcome, run, headline with interval, success rate
    table = _table(base, parent, "comparison.json")
    children = {c["info"]["run_id"]: c for c in runs["child"]}
    assert sorted(table["model"]) == sorted(MODELS) and set(table["engine"]) == {"threejs"}
    assert set(table["mlflow_run_id"]) == set(children) and set(table["status"]) == {"finished"}
    for row in table.to_dict("records"):
        child = children[row["mlflow_run_id"]]
        assert row["label"] == child["info"]["run_name"]
        for key in ("headline", "headline.lo", "headline.hi", "model_success_rate", "n_scenes"):
            assert row[key.replace(".", "_")] == pytest.approx(
                child["metrics"].get(key, float("nan")), nan_ok=True), key
