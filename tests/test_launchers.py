"""Hydra launchers beyond one process: submitit's local executor (``hydra/launcher=slurm_local``,
the SLURM launcher's code path without a cluster) and visphy's Ray launcher on a local Ray
cluster (``hydra/launcher=ray_local``) each run a small multirun (one mini scene × threejs, p5)
end to end, in processes other than the launching one; every job's rows equal those of the same
jobs under Hydra's basic launcher (frame digests, scores), and the study's MLflow parent run has
the jobs' runs as its children."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from conftest import FAST_METRICS, run_cli
from visphy_core.results.summary import STAGE_FIELDS

pytestmark = [pytest.mark.slow, pytest.mark.browser]

SWEEP = ("-m", "engine=threejs,p5", "dataset=mini", "dataset.limit=1", *FAST_METRICS,
         "run.progress=false")
#: Fields of a row that depend on when and where it was made, not on what it is.
VOLATILE = {*STAGE_FIELDS, "response_cached", "render_cached"}


def _multirun(home: Path, *launcher: str) -> tuple[dict, str]:
    """Run the sweep in a fresh VISPHY_HOME; (its study summary, the command's output)."""
    proc = run_cli(*SWEEP, *launcher, home=home, timeout=400)
    [summary] = (home / "hydra").glob("multirun-*/study_summary.json")
    return json.loads(summary.read_text()), proc.stdout + proc.stderr


def _rows(study: dict) -> dict[str, dict]:
    """engine → the job's one result row (volatile fields dropped)."""
    out = {}
    for job in study["jobs"]:
        run_dir = Path(job["run_dir"])
        [line] = (run_dir / "results.jsonl").read_text().splitlines()
        row = {k: v for k, v in json.loads(line).items() if k not in VOLATILE}
        engine = json.loads((run_dir / "summary.json").read_text())["engine"]
        out[engine] = row
    return out


@pytest.fixture(scope="module")
def new_home(tmp_path_factory, mini_root):
    def make(name: str) -> Path:
        home = tmp_path_factory.mktemp(name)
        shutil.copytree(mini_root, home / "data" / mini_root.name)
        return home
    return make


@pytest.fixture(scope="module")
def basic(new_home):
    """The same sweep under Hydra's basic launcher (jobs in the launching process)."""
    study, _ = _multirun(new_home("basic"))
    return study


def _check_study(study: dict, reference: dict, home: Path) -> None:
    assert study["status"] == "FINISHED" and study["n_completed"] == study["n_jobs"] == 2
    for job in study["jobs"]:
        summary = json.loads((Path(job["run_dir"]) / "summary.json").read_text())
        assert summary["status"] == "finished" and summary["n_scenes"] == 1
        assert Path(job["run_dir"]).is_relative_to(home)
    rows, expected = _rows(study), _rows(reference)
    assert set(rows) == {"threejs", "p5"}
    for engine, row in rows.items():
        assert row["model_success"] is True and row["frame_digests"] != "[]"
        assert row == expected[engine], engine  # frames, scores, every outcome field
        assert row["score_psnr"] > 30
    _check_mlflow(study, home)


def _check_mlflow(study: dict, home: Path) -> None:
    from mlflow.tracking import MlflowClient

    parent = study["parent"]
    assert parent["tracking_uri"] == f"sqlite:///{(home / 'mlflow.db').resolve()}"
    client = MlflowClient(tracking_uri=parent["tracking_uri"])
    assert client.get_run(parent["run_id"]).info.status == "FINISHED"
    children = client.search_runs(
        [parent["experiment_id"]],
        filter_string=f"tags.`mlflow.parentRunId` = '{parent['run_id']}'")
    assert {c.info.run_id for c in children} == {j["mlflow_run_id"] for j in study["jobs"]}
    by_id = {c.info.run_id: c for c in children}
    for job in study["jobs"]:
        child = by_id[job["mlflow_run_id"]]
        assert child.info.status == "FINISHED"
        assert child.data.tags["visphy.run_dir"] == job["run_dir"]
        assert child.data.tags["visphy.study"] == study["study"]


def _job_pids(study: dict) -> set[int]:
    records = [json.loads((Path(study["sweep_dir"]) / str(j["num"]) / "visphy_job.json")
                          .read_text()) for j in study["jobs"]]
    return {r["pid"] for r in records}


def test_basic_launcher_runs_both_jobs_in_the_launching_process(basic):
    assert len(_job_pids(basic)) == 1  # the reference really is in-process


def test_slurm_local_runs_the_sweep_in_submitit_processes(basic, new_home):
    home = new_home("submitit")
    study, _ = _multirun(home, "hydra/launcher=slurm_local")
    _check_study(study, basic, home)
    assert len(_job_pids(study)) == 2  # one process per job
    logs = sorted(Path(study["sweep_dir"]).glob(".submitit/*/*_log.out"))
    assert len(logs) == 2 and all("run directory:" in p.read_text() for p in logs)


def test_ray_local_runs_the_sweep_as_ray_tasks(basic, new_home):
    home = new_home("ray")
    study, output = _multirun(home, "hydra/launcher=ray_local",
                              "hydra.launcher.init.num_cpus=2",
                              "hydra.launcher.remote.num_cpus=1")
    _check_study(study, basic, home)
    assert "Ray launcher: starting a local Ray cluster" in output
    assert "(run_job_remote pid=" in output  # the job's output, forwarded from its Ray worker
    assert len(_job_pids(study)) == 2


def test_ray_jobs_receive_the_forwarded_environment_only():
    from visphy_plugins.launchers.ray_jobs import forwarded_env

    env = {"VISPHY_HOME": "/shared/visphy", "VISPHY_STUDY_JOB": "/sweep/0",
           "OPENAI_API_KEY": "sk-x", "TORCH_HOME": "/shared/torch", "PATH": "/usr/bin"}
    assert forwarded_env(["VISPHY_*", "TORCH_HOME"], env) == {
        "TORCH_HOME": "/shared/torch", "VISPHY_HOME": "/shared/visphy"}
