"""A study tracked on a real ``mlflow server`` (sqlite backend, local artifact store, loopback),
checked only through the server's REST API: the parent run, its children, their params, metrics,
system tags and artifacts (the per-scene Parquet table, the reports, the study analysis)."""

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
    """The baselines study (two pixel-space baselines, one scene of the tiny fixture dataset)
    tracked on the server; (base URL, the experiment's runs by role, the study folder, the
    finished process)."""
    home = tmp_path_factory.mktemp("home")
    proc = run_cli("-m", "experiment=baselines", f"model={','.join(MODELS)}", "dataset=tiny",
                   "dataset.limit=1", f"tracking.uri={server}", "tracking.log_videos=true",
                   "run.progress=false", home=home)
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
    assert parent["metrics"] == {"n_jobs": 2.0, "n_completed": 2.0, "n_failed": 0.0}
    assert len(runs["child"]) == 2
    for child in runs["child"]:
        assert child["tags"]["mlflow.parentRunId"] == parent["info"]["run_id"]
        assert child["info"]["status"] == "FINISHED"
    assert parent["info"]["run_id"] in proc.stdout  # the printed link names the parent run


def test_children_carry_params_metrics_and_system_tags(study):
    _, runs, _, _ = study
    assert {c["tags"]["visphy.model"] for c in runs["child"]} == set(MODELS)
    for child in runs["child"]:
        tags, params, metrics = child["tags"], child["params"], child["metrics"]
        assert tags["visphy.engine"] == "threejs" and tags["visphy.study"] == "baselines"
        assert tags["visphy.benchmark_version"] == "tiny:visphybench/sub"
        commit = tags["mlflow.source.git.commit"]
        assert commit == tags["visphy.git_commit"] and len(commit) == 40
        assert subprocess.run(["git", "-C", str(REPO), "merge-base", "--is-ancestor", commit,
                               "HEAD"]).returncode == 0  # this checkout's commit (or HEAD's past)
        assert tags["visphy.prompt_version"]
        assert tags["mlflow.runName"] == f"model={tags['visphy.model']} engine=threejs"
        assert params["model.name"] == tags["visphy.model"] and params["dataset.limit"] == "1"
        summary = json.loads(Path(tags["visphy.run_dir"], "summary.json").read_text())
        psnr = summary["metrics"]["psnr"]
        assert metrics["psnr"] == pytest.approx(psnr["mean_model_success"])
        assert metrics["psnr_n"] == psnr["n_model_success"] == 1
        assert metrics["psnr_with_fallbacks"] == pytest.approx(psnr["mean_with_fallbacks"])
        assert metrics["psnr_with_fallbacks_n"] == psnr["n_with_fallbacks"]
        assert metrics["model_success_rate"] == 1.0 and metrics["n_scenes"] == 1.0


def test_children_artifacts_hold_the_scene_table_report_and_videos(study):
    base, runs, _, _ = study
    for child in runs["child"]:
        files = _files(base, child)
        for name in ("results.parquet", "summary.json", "config.yaml", "manifest.json"):
            assert files.get(name) is False, name
        assert files.get("report") is True and "report/index.html" in _files(base, child,
                                                                              "report")
        [scene] = _files(base, child, "videos")
        assert f"{scene}/video.mp4" in _files(base, child, scene)
        table = pd.read_parquet(io.BytesIO(_download(base, child, "results.parquet")))
        assert list(table["scene_id"]) == [scene.split("/")[-1]]
        assert table["score_psnr"].iloc[0] == pytest.approx(child["metrics"]["psnr"])


def test_the_parent_holds_the_study_analysis_and_report(study):
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
