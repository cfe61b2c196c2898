"""``score RUN_DIR``: a finished run scored again with other metrics or judges, with no model
call and no render (the model's fake server stays up and counts; Chromium is unavailable to the
re-scoring process), the original run left intact, unchanged columns equal, the cache reused,
a judge added through its real SDK against a fake server, refused overrides and bad run
directories as one-line errors, and an interrupted run re-scored over its finished rows."""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO
from visphy_plugins.datasets.tiny import make_tiny_dataset
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.fake_server import ok
from visphy_plugins.testing.replies import reply

pytestmark = pytest.mark.browser

KEY = "sk-test-rescore-4d2a"
NEW_METRIC = "flow_epe_dis"


def _cli(*args: str, home: Path, env: dict | None = None, check: bool = True
         ) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    full.update(VISPHY_HOME=str(home), OPENAI_API_KEY=KEY, **(env or {}))
    proc = subprocess.run([sys.executable, "-m", "visphy_core", *args], cwd=REPO, env=full,
                          capture_output=True, text=True, timeout=300)
    if check:
        assert proc.returncode == 0, f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


def _rows(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "results.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A two-scene run of gpt41 (real OpenAI SDK, loopback fake) on the tiny dataset, rendered
    by Chromium; the fake stays up for the module and counts every model call."""
    base = tmp_path_factory.mktemp("rescore")
    root = make_tiny_dataset(base / "tiny", 2)
    server = FakeOpenAIServer(default=lambda req: ok(reply("html"), {"input_tokens": 100,
                                                                    "output_tokens": 50}))
    with server:
        home = base / "home"
        args = ("model=gpt41", f"model.base_url={server.url}/v1", "engine=threejs",
                "dataset=original", f"dataset.root={root}", "metrics.names=[psnr,ssim]",
                "run.progress=false", "tracking=none")
        _cli(*args, home=home)
        (run_dir,) = (home / "runs").iterdir()
        assert server.count() == 2
        yield {"home": home, "run": run_dir, "server": server, "root": root, "base": base}


@pytest.fixture(scope="module")
def no_chromium(finished) -> dict:
    """An environment in which Chromium cannot start (VISPHY_CHROMIUM names a stub that is no
    browser): proven by rendering one reply under it."""
    stub = finished["base"] / "not-chromium"
    stub.write_text("#!/bin/sh\nexit 1\n")
    stub.chmod(stub.stat().st_mode | stat.S_IXUSR)
    env = {"VISPHY_CHROMIUM": str(stub)}
    out = finished["base"] / "control"
    _cli("render", str(finished["run"] / "scenes" / "task10000_000" / "response.txt"),
         "--engine", "threejs", "--scene", "task10000_000", "--dataset", "original",
         f"dataset.root={finished['root']}", "--metrics", "psnr", "run.cache=false",
         "tracking=none", "-o", str(out), home=finished["home"], env=env, check=False)
    control = json.loads((out / "result.json").read_text())
    assert control["failure_class"] == "infra_error", control
    assert "failed to start" in control["failure_detail"]
    return env


def test_one_more_metric_without_a_model_call_or_a_render(finished, no_chromium):
    """The run was not tracked; its re-scoring is (tracking=mlflow is the default)."""
    run = finished["run"]
    before_rows = (run / "results.jsonl").read_bytes()
    calls = (run / "calls.jsonl").read_bytes()
    proc = _cli("score", str(run), f"metrics.names=[psnr,ssim,{NEW_METRIC}]", "run.cache=false",
                "tracking=mlflow", home=finished["home"], env=no_chromium)
    assert finished["server"].count() == 2  # the model was not asked again
    assert (run / "results.jsonl").read_bytes() == before_rows  # the original is intact
    (new,) = [p for p in (finished["home"] / "runs").iterdir() if ".rescored-" in p.name]
    assert new.name.startswith(run.name)
    assert (new / "calls.jsonl").read_bytes() == calls
    old = {r["scene_id"]: r for r in _rows(run)}
    rows = _rows(new)
    assert [r["scene_id"] for r in rows] == list(old)
    for row in rows:
        before = old[row["scene_id"]]
        assert row["system_success"] and before["system_success"]
        for key in ("model_success", "attempts", "frame_digests", "render_wall_s", "flags"):
            assert row[key] == before[key]
        for view in ("", ".aligned"):
            assert isinstance(row[f"score_{NEW_METRIC}{view}"], float)
        assert isinstance(row[f"score_paper.{NEW_METRIC}"], float)
        for col in (c for c in before if c.startswith("score_")):
            assert row[col] == before[col], col
        assert os.stat(new / "scenes" / row["scene_id"] / "video.mp4").st_ino == \
            os.stat(run / "scenes" / row["scene_id"] / "video.mp4").st_ino  # linked, not copied
    summary = json.loads((new / "summary.json").read_text())
    assert summary["rescore_calls"] == {} and summary["model_success"] == 2
    assert summary["metrics"][NEW_METRIC]["n_model_success"] == 2
    manifest = json.loads((new / "manifest.json").read_text())
    assert manifest["rescored_from"]["run_dir"] == str(run)
    assert manifest["rescore"]["changed"] == {
        "metrics.names": {"before": ["psnr", "ssim"], "after": ["psnr", "ssim", NEW_METRIC]},
        "run.cache": {"before": True, "after": False},
        "tracking.backend": {"before": "none", "after": "mlflow"}}
    assert "calls made now: none" in proc.stdout
    # the run's own call lines (the oracle's 'generate' calls of the original run) are labelled
    flat = " ".join(proc.stdout.split())  # the summary folds long lines at 100 columns
    heading = flat.index("(the original run's included; the calls made by this re-score")
    assert heading < flat.index("generate: ")
    # a new MLflow run, tagged with the run it re-scores, in the store the printed command opens
    from mlflow.tracking import MlflowClient

    (uri,) = [line.split("--backend-store-uri ", 1)[1] for line in proc.stdout.splitlines()
              if line.startswith("MLflow: ") and " ui --backend-store-uri " in line]
    assert uri == manifest["tracking"]["mlflow"]["tracking_uri"]
    mlrun = MlflowClient(tracking_uri=uri).get_run(manifest["tracking"]["mlflow"]["run_id"])
    assert mlrun.data.tags["visphy.rescored_from"] == str(run)
    assert mlrun.info.run_name.endswith(" · re-scored")  # beside the run it re-scores
    assert mlrun.data.metrics[NEW_METRIC] == summary["metrics"][NEW_METRIC]["mean_model_success"]


def test_in_place_reuses_the_cache_and_keeps_a_backup(finished, no_chromium, tmp_path):
    run = tmp_path / finished["run"].name
    shutil.copytree(finished["run"], run)
    original = (run / "results.jsonl").read_bytes()
    # a headline's details from an earlier scoring: these metrics make no headline, so the
    # file must go (into the backup) rather than stay beside scores it does not describe
    stale = run / "scenes" / "task10000_000" / "headline.json"
    stale.write_text('{"value": 0.5}')
    _cli("score", str(run), "--in-place", f"metrics.names=[psnr,ssim,{NEW_METRIC}]",
         "tracking=none", home=finished["home"], env=no_chromium)
    (backup,) = run.glob("rescore-backup-*")
    assert (backup / "results.jsonl").read_bytes() == original
    assert not stale.exists()
    assert (backup / "scenes" / "task10000_000" / "headline.json").read_text() == \
        '{"value": 0.5}'
    assert all(isinstance(r[f"score_{NEW_METRIC}"], float) for r in _rows(run))
    summary = json.loads((run / "summary.json").read_text())
    assert summary["run_dir"] == str(run) and summary["rescored_from"] == str(run)
    # psnr and ssim were cached by the run, flow_epe_dis by the first re-scoring: no miss
    assert summary["cache"]["score"]["misses"] == 0 and summary["cache"]["score"]["hits"] > 0


def test_a_judge_added_by_rescoring_calls_only_the_judge(finished, no_chromium):
    judge = FakeOpenAIServer(default=lambda req: ok('{"score": 6, "justification": "late"}'))
    run = finished["run"]
    with judge:
        _cli("score", str(run), "judge=gpt_frames", f"judge.gpt_frames.base_url={judge.url}/v1",
             "tracking=none", home=finished["home"], env=no_chromium)
        assert judge.count() == 2
    assert finished["server"].count() == 2
    new = max((p for p in (finished["home"] / "runs").iterdir() if ".rescored-" in p.name),
              key=lambda p: p.stat().st_mtime)
    assert all(r["score_judge_gpt_frames"] == 6.0 for r in _rows(new))
    added = (new / "calls.jsonl").read_text().splitlines()[len(
        (run / "calls.jsonl").read_text().splitlines()):]
    assert [json.loads(line)["stage"] for line in added] == ["judge", "judge"]
    summary = json.loads((new / "summary.json").read_text())
    assert summary["rescore_calls"] == {"judge": 2}
    assert summary["judges"]["gpt_frames"]["n_valid"] == 2


@pytest.mark.parametrize("args, needle", [
    (["model=gpt5"], "model=gpt5 cannot be applied to a finished run: it changes who wrote"),
    (["engine.timeout_s=5"], "it changes how the programs were rendered"),
    (["run.retry=false"], "only run.progress and run.cache apply"),
    (["metrics.names=[psnrr]"], "psnrr is not an installed metric"),
    (["judge.gemini.base_url=http://x"], "the run has no judge 'gemini'"),
])
def test_refused_overrides_are_one_line_errors(finished, capsys, args, needle):
    from visphy_core.cli.main import main

    assert main(["score", str(finished["run"]), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0], err


def test_a_missing_or_foreign_folder_is_a_one_line_error(tmp_path, capsys):
    from visphy_core.cli.main import main

    (tmp_path / "stuff").mkdir()
    assert main(["score", str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip() == f"error: score: no run directory at " \
                                              f"{tmp_path / 'nope'}"
    assert main(["score", str(tmp_path / "stuff")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a visphy run directory" in err[0]
    assert not any(".rescored-" in p.name for p in tmp_path.iterdir())


def test_an_interrupted_run_is_rescored_over_its_finished_rows(finished, no_chromium,
                                                               tmp_path):
    run = tmp_path / finished["run"].name
    shutil.copytree(finished["run"], run)
    first, second = (run / "results.jsonl").read_text().splitlines()
    (run / "results.jsonl").write_text(first + "\n" + second[:40])  # killed mid-row
    manifest = json.loads((run / "manifest.json").read_text())
    (run / "manifest.json").write_text(json.dumps(dict(manifest, status="interrupted")))
    proc = _cli("score", str(run), f"metrics.names=[psnr,{NEW_METRIC}]", "tracking=none",
                home=finished["home"], env=no_chromium)
    (new,) = [p for p in tmp_path.iterdir() if ".rescored-" in p.name]
    rows = _rows(new)
    assert [r["scene_id"] for r in rows] == [json.loads(first)["scene_id"]]
    assert isinstance(rows[0][f"score_{NEW_METRIC}"], float) and "score_ssim" not in rows[0]
    summary = json.loads((new / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["n_scenes"] == 1
    assert "(the run was interrupted: its finished rows only)" in proc.stdout
    assert (run / "results.jsonl").read_text().endswith(second[:40])  # untouched


def test_the_spec_track_and_twin_clips_are_read_back_not_rendered(visphy_home, no_chromium):
    """A generated scene (it has a ground-truth spec): the run replayed S and rendered the
    twin; re-scoring with one more metric scores both clips it finds, with no browser."""
    from conftest import run_cli

    run_cli("model=oracle", "dataset=mini", "dataset.limit=1", "metrics.names=[psnr]",
            "metrics.variance_norm=true", "tracking=none", "run.progress=false",
            home=visphy_home)
    (run,) = (visphy_home / "runs").iterdir()
    run_cli("score", str(run), "metrics.names=[psnr,ssim]", "tracking=none",
            home=visphy_home, env=no_chromium)
    (new,) = [p for p in (visphy_home / "runs").iterdir() if ".rescored-" in p.name]
    (before,), (row,) = _rows(run), _rows(new)
    assert row["spec_track"] == before["spec_track"] == "rendered"
    for col in ("ssim", "spec.ssim", "norm.ssim", "spec.norm.ssim"):
        assert isinstance(row[f"score_{col}"], float), col
    for col in (c for c in before if c.startswith("score_")):
        assert row[col] == before[col], col
    for clip in ("spec_video.mp4", "twin_video.mp4"):
        assert os.stat(new / "scenes" / row["scene_id"] / clip).st_ino == \
            os.stat(run / "scenes" / row["scene_id"] / clip).st_ino
