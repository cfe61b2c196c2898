"""Studies as Hydra experiments: every study composes at every point of its sweep, and studies run
end to end offline (a tiny selection of the mini set) with their analysis, report and records."""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import time
from itertools import combinations
from pathlib import Path

import pandas as pd
import pytest

from conftest import REPO, run_cli

STUDIES = ("leaderboard", "cross_engine", "judge_replacement", "no_detection", "forecast_only",
           "retry_ablation", "param_recovery", "baselines")
PARAM_METRICS = {"param_gravity_err", "param_restitution_err", "param_friction_err",
                 "param_mass_ratio_err", "param_speed_err"}


# ------------------------------------------------------------------------------ composition


def sweep_points(name: str) -> tuple[list[list[str]], dict]:
    """Every job's overrides of ``-m experiment=<name>`` (as Hydra's basic sweeper splits the
    file's sweep) and the composed hydra node."""
    from hydra import compose, initialize_config_module
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    from visphy_core.api.registry import get_registry

    get_registry()
    GlobalHydra.instance().clear()
    with initialize_config_module(config_module="visphy_conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"experiment={name}"],
                      return_hydra_config=True)
    GlobalHydra.instance().clear()
    params = OmegaConf.to_container(cfg.hydra.sweeper.params) or {}
    parsed = OverridesParser.create().parse_overrides([f"{k}={v}" for k, v in params.items()])
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper

    [points] = BasicSweeper.split_arguments(parsed, None)
    return points, OmegaConf.to_container(cfg.hydra)


def test_the_shipped_studies():
    found = {p.stem for p in (REPO / "conf" / "experiment").glob("*.yaml")} - {"smoke"}
    assert found == set(STUDIES)


@pytest.mark.parametrize("name", STUDIES)
def test_every_point_of_the_sweep_composes_and_passes_the_checks(name):
    from omegaconf import OmegaConf

    from visphy_core.config.check import compose_all

    points, hydra = sweep_points(name)
    assert len(points) >= 1
    assert hydra["sweep"]["dir"] == \
        "${paths.root}/studies/${hydra.runtime.choices.experiment}-${now:%Y-%m-%d_%H-%M-%S}"
    assert hydra["runtime"]["choices"]["experiment"] == name
    configs = []
    for point in points:
        [cfg] = compose_all([f"experiment={name}", *point])  # check_values: names, ranges…
        resolved = OmegaConf.to_container(cfg, resolve=True)  # what --cfg job --resolve shows
        assert resolved["dataset"]["name"] == "visphybench_test"
        configs.append(resolved)
    models = {c["model"]["name"] for c in configs}
    engines = {c["engine"]["name"] for c in configs}
    if name == "leaderboard":
        assert engines == {"threejs", "p5"} and "oracle" in models and len(points) >= 4
    elif name == "cross_engine":
        assert engines == {"threejs", "p5", "svg", "manim", "blender"} and len(models) == 1
        # the exact and the native oracle on every engine (tests/test_native_reference.py)
        assert {(c["engine"]["name"], c["model"]["style"]) for c in configs} == \
            {(e, s) for e in engines for s in ("exact", "native")}
    elif name == "judge_replacement":
        assert all(set(c["judge"]) == {"gemini", "gpt_frames", "qwen_vl", "claude_frames"}
                   for c in configs)
    elif name == "no_detection":
        assert {c["prompt"]["detection"] for c in configs} == {True, False}
    elif name == "forecast_only":
        assert {c["prompt"]["forecast_only"] for c in configs} == {True, False}
        assert "flow_extrapolate" in models
    elif name == "retry_ablation":
        assert {(c["engine"]["name"], c["run"]["retry"]) for c in configs} == \
            {("threejs", True), ("threejs", False), ("p5", True), ("p5", False)}
    elif name == "param_recovery":
        assert all(PARAM_METRICS <= set(c["metrics"]["names"]) for c in configs)
    elif name == "baselines":
        assert {"static", "flow_extrapolate"} <= models


def test_cfg_job_of_a_study_resolves_on_the_command_line(tmp_path):
    proc = run_cli("--cfg", "job", "--resolve", "experiment=cross_engine", home=tmp_path)
    assert "name: visphybench_test" in proc.stdout and "${" not in proc.stdout


def test_smoke_still_composes():
    from visphy_core.config.check import compose

    cfg = compose(["experiment=smoke"])
    assert cfg.dataset.limit == 1 and cfg.tracking.backend == "none"


# ------------------------------------------------------------------------------ end to end


@pytest.fixture(scope="module")
def home(tmp_path_factory, mini_root) -> Path:
    home = tmp_path_factory.mktemp("studies")
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


def _study_dir(home: Path, name: str) -> Path:
    [found] = sorted((home / "studies").glob(f"{name}-*"))
    return found


@pytest.fixture(scope="module")
def cross_engine(home):
    """The cross-engine study, the exact oracle on two browser engines (a command-line sweep
    replaces the file's two oracles and five engines), three mini scenes, cheap metrics, no
    tracking."""
    proc = run_cli("-m", "experiment=cross_engine", "model=oracle", "engine=p5,svg",
                   "dataset=mini", "dataset.limit=3", "tracking=none", "run.progress=false",
                   home=home)
    return proc, _study_dir(home, "cross_engine")


@pytest.mark.slow
@pytest.mark.browser
def test_cross_engine_runs_the_requested_jobs_and_records_them(cross_engine):
    proc, study = cross_engine
    summary = json.loads((study / "study_summary.json").read_text())
    assert summary["status"] == "FINISHED" and summary["n_completed"] == summary["n_jobs"] == 2
    assert sorted(j["label"] for j in summary["jobs"]) == [
        "model=oracle engine=p5", "model=oracle engine=svg"]
    assert summary["sweep"] == {"model": "oracle", "engine": "p5,svg"}
    for job in summary["jobs"]:
        run = json.loads((Path(job["run_dir"]) / "summary.json").read_text())
        assert run["status"] == "finished" and run["n_scenes"] == 3
        assert run["engine"] == job["label"].split("engine=")[1]
    assert "study cross_engine: 2/2 jobs completed (finished)" in proc.stdout
    assert f"folder: {study}" in proc.stdout


@pytest.mark.slow
@pytest.mark.browser
def test_cross_engine_prints_the_spearman_table_and_a_matrix_per_metric(cross_engine):
    proc, study = cross_engine
    assert proc.stdout.count("Spearman ρ over scenes") == 1
    for metric in ("psnr", "ssim"):
        assert re.search(rf"│ {metric}\s+│", proc.stdout), proc.stdout
        matrix = pd.read_csv(study / "analysis" / f"spearman_{metric}.csv")
        assert len(matrix) == 2  # one row per engine's run
    board = pd.read_csv(study / "analysis" / "leaderboard.csv")
    assert len(board) == 2
    assert (study / "report" / "index.html").is_file()


@pytest.fixture(scope="module")
def fake_providers(tmp_path_factory):
    """``python -m visphy_plugins.testing.serve`` as a user starts it; its JSON description."""
    out = tmp_path_factory.mktemp("serve") / "fake.json"
    proc = subprocess.Popen([sys.executable, "-m", "visphy_plugins.testing.serve", "--json",
                             str(out)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not out.is_file() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.1)
        assert out.is_file(), "the fake provider servers did not start"
        yield json.loads(out.read_text())
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)


@pytest.fixture(scope="module")
def judge_study(tmp_path_factory, fake_providers):
    """The judge-replacement study: the static baseline on the three scenes of the tiny fixture
    dataset, the four API judges answered by the fake servers."""
    home = tmp_path_factory.mktemp("judges")
    proc = run_cli("-m", "experiment=judge_replacement", "model=static", "dataset=tiny",
                   "tracking=none", "run.progress=false",
                   *fake_providers["judge_overrides"], home=home,
                   env=dict(fake_providers["env"], VISPHY_ENV_FILE=str(home / "no.env")))
    return proc, _study_dir(home, "judge_replacement")


@pytest.mark.slow
def test_judge_replacement_against_the_fake_servers_tabulates_agreement(judge_study):
    proc, study = judge_study
    summary = json.loads((study / "study_summary.json").read_text())
    assert summary["status"] == "FINISHED" and summary["n_completed"] == 1
    [job] = summary["jobs"]
    run = json.loads((Path(job["run_dir"]) / "summary.json").read_text())
    assert {k: v["n_valid"] for k, v in run["judges"].items()} == \
        {"gemini": 3, "gpt_frames": 3, "qwen_vl": 3, "claude_frames": 3}
    judges = pd.read_csv(study / "analysis" / "judges.csv")
    # every pair of the four judges once (no human ratings here), each over the 3 scenes
    columns = [f"judge_{j}" for j in ("gemini", "gpt_frames", "qwen_vl", "claude_frames")]
    pairs = [frozenset(p) for p in zip(judges["A"], judges["B"])]
    assert len(pairs) == 6 and set(pairs) == {frozenset(p) for p in combinations(columns, 2)}
    assert judges["n"].tolist() == [3] * 6, judges
    assert "study judge_replacement: 1/1 jobs completed" in proc.stdout


# ------------------------------------------------------------------------------ ending early


def _fake_study(tmp_path: Path, jobs: list[dict]) -> Path:
    from visphy_core.results import study_records as records

    sweep = tmp_path / "studies" / "leaderboard-x"
    records.write_json(records.study_file(sweep), {"name": "leaderboard", "status": "running",
                                                   "overrides": [], "parent": None})
    for num, job in enumerate(jobs):
        records.write_job(sweep / "jobs" / str(num), num=num, sweep_dir=str(sweep), **job)
    return sweep


@pytest.mark.slow
@pytest.mark.browser
def test_a_study_with_a_failed_job_is_analysed_over_the_others(cross_engine, tmp_path):
    from visphy_core.study.finish import finish_study

    _, study = cross_engine
    done = json.loads((study / "study_summary.json").read_text())["jobs"]
    sweep = _fake_study(tmp_path, [
        {"label": "a", "status": "completed", "run_dir": done[0]["run_dir"]},
        {"label": "b", "status": "completed", "run_dir": done[1]["run_dir"]},
        {"label": "c", "status": "failed", "error": "RuntimeError: boom"}])
    summary = finish_study(sweep, ended_early=True)
    assert summary["status"] == "FAILED" and summary["n_completed"] == 2
    assert summary["jobs"][2]["error"] == "RuntimeError: boom"
    assert len(pd.read_csv(sweep / "analysis" / "leaderboard.csv")) == 2
    assert json.loads((sweep / "study.json").read_text())["status"] == "failed"
    assert finish_study(sweep)["status"] == "failed"  # idempotent: finished once


def test_a_study_whose_job_never_returned_ends_killed_without_analysis(tmp_path):
    from visphy_core.study.finish import finish_study

    sweep = _fake_study(tmp_path, [{"label": "a", "status": "running"}])
    summary = finish_study(sweep, ended_early=True)
    assert summary["status"] == "KILLED" and not (sweep / "analysis").exists()
    assert summary["jobs"][0]["status"] == "aborted"
    assert json.loads((sweep / "jobs" / "0" / "visphy_job.json").read_text())["status"] == \
        "aborted"
