"""The analysis on real runs made once for this module through the CLI, offline: the oracle and
the static baseline on Three.js (scored by two judges served by the fake Gemini and OpenAI
servers, and rated by two humans), the oracle on p5.js, and recorded replies replayed with and
without the repair call (one scene rescued by the repair, one falling back).

Every number the analysis reports is checked against an independent computation from the run's
own files (``summary.json``, ``results.jsonl``, ``human_ratings.jsonl``) with scipy and numpy.
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from scipy import stats

from conftest import run_cli
from visphy_core.analysis.agreement import krippendorff_alpha
from visphy_core.analysis.load import load_runs
from visphy_core.analysis.study import analyse
from visphy_plugins.testing.fake_gemini import FakeGeminiServer
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.fake_server import ok

pytestmark = pytest.mark.browser

COMMON = ("dataset.limit=3", "run.progress=false", "tracking=none", "metrics.spec_track=false",
          "metrics.variance_norm=false")
METRICS = ("metrics.names=[psnr,ssim,flow_epe_dis,param_gravity_err,param_restitution_err,"
           "param_speed_err]")
NO_CODE = "I would rather describe the scene than write a program for it."
ORACLE, STATIC, P5 = "oracle/threejs", "static/threejs", "oracle/p5"
RETRY_ON, RETRY_OFF = "replay/threejs run.retry=true", "replay/threejs run.retry=false"


def _verdict(req) -> object:
    """A judge score from the request's bytes (the clips differ per scene and per run)."""
    score = 1 + int(hashlib.sha256(req.body).hexdigest()[:8], 16) % 10
    return ok(json.dumps({"score": score, "justification": "scripted"}))


def _run_dir(home: Path, needle: str) -> Path:
    (found,) = [p for p in (home / "runs").iterdir() if needle in p.name]
    return found


def _rows(run_dir: Path) -> pd.DataFrame:
    return pd.DataFrame([json.loads(x) for x in
                         (run_dir / "results.jsonl").read_text().splitlines()])


def _rate(run_dir: Path, ratings: dict[str, list[int]]) -> list[dict]:
    """Ratings as the rating page writes them (a re-rating first, which the last line beats)."""
    lines = []
    for rater, values in ratings.items():
        for scene, value in zip(sorted(_rows(run_dir)["scene_id"]), values):
            item = hashlib.sha1(f"{run_dir.name}/{scene}".encode()).hexdigest()[:12]
            lines.append({"scene_id": scene, "rater": rater, "rating": 3, "item": item,
                          "ts": "2026-01-01T00:00:00", "comment": None})
            lines.append({"scene_id": scene, "rater": rater, "rating": value, "item": item,
                          "ts": "2026-01-01T00:01:00", "comment": "ok"})
    (run_dir / "human_ratings.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    return lines


@pytest.fixture(scope="module")
def study(mini_root, tmp_path_factory):
    """Five runs of three mini scenes, rated, then analysed (everything that applies)."""
    root = tmp_path_factory.mktemp("analysis")
    home = root / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    env = {"GEMINI_API_KEY": "test-gemini-analysis", "OPENAI_API_KEY": "sk-test-analysis"}
    replies = root / "replies"

    def oracle_then_replays(gem, oai):
        run_cli("model=oracle", *COMMON, METRICS, "judge=[gemini,gpt_frames]",
                f"judge.gemini.base_url={gem.url}", f"judge.gpt_frames.base_url={oai.url}/v1",
                home=home, env=env)
        oracle = _run_dir(home, "oracle_threejs")
        ids = list(_rows(oracle)["scene_id"])
        replies.mkdir()
        (replies / f"{ids[0]}.txt").write_text(NO_CODE)                    # rescued by repair
        shutil.copy(oracle / "scenes" / ids[0] / "response.txt",
                    replies / f"{ids[0]}.attempt2.txt")
        (replies / f"{ids[1]}.txt").write_text(NO_CODE)                    # falls back
        shutil.copy(oracle / "scenes" / ids[2] / "response.txt", replies / f"{ids[2]}.txt")
        with ThreadPoolExecutor(2) as pool:
            replays = [pool.submit(run_cli, "model=replay", f"model.source={replies}",
                                   f"run.retry={retry}", *COMMON, METRICS, home=home)
                       for retry in ("true", "false")]
            for job in replays:
                job.result()

    with FakeGeminiServer(default=_verdict) as gem, FakeOpenAIServer(default=_verdict) as oai:
        with ThreadPoolExecutor(3) as pool:
            jobs = [pool.submit(oracle_then_replays, gem, oai),
                    pool.submit(run_cli, "model=static", *COMMON, METRICS,
                                "judge=[gemini,gpt_frames]", f"judge.gemini.base_url={gem.url}",
                                f"judge.gpt_frames.base_url={oai.url}/v1", home=home, env=env),
                    pool.submit(run_cli, "model=oracle", "engine=p5", *COMMON, METRICS,
                                home=home)]
            for job in jobs:
                job.result()
    ratings = {
        ORACLE: _rate(_run_dir(home, "oracle_threejs"), {"ann": [5, 4, 5], "bob": [4, 4, 5]}),
        STATIC: _rate(_run_dir(home, "static_threejs"), {"ann": [1, 2, 1], "bob": [2, 1, 1]}),
    }
    runs = load_runs([home / "runs"])
    out = analyse(runs, root / "analysis", resamples=2000)
    return {"home": home, "root": root, "runs": {r.label: r for r in runs}, "out": out,
            "ratings": ratings}


def _same(value, expected) -> bool:
    if expected is None:
        return bool(pd.isna(value))
    return value == pytest.approx(expected)


def test_runs_are_labelled_by_what_sets_them_apart(study):
    assert set(study["runs"]) == {ORACLE, STATIC, P5, RETRY_ON, RETRY_OFF}
    table = study["out"].tables["runs"]
    assert sorted(table["run"]) == sorted(study["runs"])
    assert all(Path(p).is_dir() for p in table["run_dir"])


def test_leaderboard_agrees_with_every_summary_in_both_views(study):
    board = study["out"].tables["leaderboard_all"].set_index("run")
    checked = 0
    for label, run in study["runs"].items():
        assert board.loc[label, "n_scenes"] == run.summary["n_scenes"] == 3
        assert board.loc[label, "model success rate"] == pytest.approx(
            run.summary["model_success_rate"])
        assert board.loc[label, "fallbacks"] == run.summary["fallbacks"]
        for col, info in run.summary["metrics"].items():
            arrow = {"higher": "↑", "lower": "↓"}[info["direction"]]
            assert _same(board.loc[label, f"{col} {arrow}"], info["mean_model_success"]), col
            assert board.loc[label, f"{col} n"] == info["n_model_success"]
            assert _same(board.loc[label, f"{col} {arrow} +fb"], info["mean_with_fallbacks"])
            assert board.loc[label, f"{col} n +fb"] == info["n_with_fallbacks"]
            checked += 1
    assert checked > 40
    printed = study["out"].tables["leaderboard"]
    assert list(printed.columns[:4]) == ["run", "n_scenes", "model success rate", "fallbacks"]
    assert {"psnr ↑", "ssim ↑", "flow_epe_dis ↓", "judge_gemini ↑", "judge_gpt_frames ↑",
            "human ↑", "human α"} <= set(printed.columns)


def test_retry_and_failure_tables_from_replayed_replies(study):
    retry = study["out"].tables["retry"].set_index("run")
    assert retry.loc[RETRY_ON, ["first attempt", "after retry", "rescued"]].tolist() == [1, 2, 1]
    assert retry.loc[RETRY_OFF, ["first attempt", "after retry", "rescued"]].tolist() == [1, 1, 0]
    assert retry.loc[RETRY_ON, "success (retry)"] == pytest.approx(2 / 3)
    assert retry.loc[ORACLE, "success (first)"] == 1.0
    assert retry.loc["paper: threejs (reference)", "success (first)"] == 0.979
    failures = study["out"].tables["failures"].set_index("run")
    for label in (RETRY_ON, RETRY_OFF):
        rows = _rows(study["runs"][label].run_dir)
        expected = rows.loc[~rows["model_success"], "failure_class"].value_counts().to_dict()
        assert expected and sum(expected.values()) == (1 if label == RETRY_ON else 2)
        for cls, count in expected.items():
            assert failures.loc[label, cls] == count
        assert failures.loc[label, "fallbacks"] == rows["fallback"].sum()
    assert failures.loc[RETRY_ON, "repaired"] == 1
    assert failures.loc[ORACLE, "infra_error (not evaluable)"] == 0


def test_spearman_between_engines_is_scipys_over_common_scenes(study):
    out = study["out"]
    a = _rows(study["runs"][ORACLE].run_dir).set_index("scene_id")["score_psnr"]
    b = _rows(study["runs"][P5].run_dir).set_index("scene_id")["score_psnr"]
    common = sorted(set(a.index) & set(b.index))
    expected = stats.spearmanr(a[common], b[common])
    long = out.tables["spearman"]
    row = long[(long["metric"] == "psnr") & long["A"].isin([ORACLE, P5])
               & long["B"].isin([ORACLE, P5])].iloc[0]
    assert row["n"] == 3
    assert row["ρ"] == pytest.approx(expected.statistic)
    assert row["p"] == pytest.approx(expected.pvalue)
    matrix = out.tables["spearman_psnr"].set_index("run")
    assert matrix.loc[P5, ORACLE] == pytest.approx(expected.statistic)
    assert matrix.loc[ORACLE, ORACLE] == 1.0
    mean = out.tables["spearman_mean"].set_index("metric").loc["psnr"]
    defined = long.loc[long["metric"] == "psnr", "ρ"].dropna()
    assert mean["mean ρ"] == pytest.approx(defined.mean()) and mean["pairs"] == len(defined)


def test_judges_and_humans_agree_as_scipy_and_krippendorff_say(study):
    out = study["out"]
    pooled = pd.concat([_rows(study["runs"][label].run_dir) for label in (ORACLE, STATIC)])
    gem, gpt = pooled["score_judge_gemini"], pooled["score_judge_gpt_frames"]
    judges = out.tables["judges"].set_index(["A", "B"])
    row = judges.loc[("judge_gemini", "judge_gpt_frames")]
    assert row["n"] == 6
    assert gem.nunique() > 1 and gpt.nunique() > 1        # the scripted verdicts vary
    assert row["pearson r"] == pytest.approx(stats.pearsonr(gem, gpt).statistic)
    assert row["spearman ρ"] == pytest.approx(stats.spearmanr(gem, gpt).statistic)
    assert row["spearman p"] == pytest.approx(stats.spearmanr(gem, gpt).pvalue)
    human_means = {"ann": [5, 4, 5], "bob": [4, 4, 5]}
    per_scene = (np.array(human_means["ann"]) + np.array(human_means["bob"])) / 2
    board = out.tables["leaderboard"].set_index("run")
    assert board.loc[ORACLE, "human ↑"] == pytest.approx(per_scene.mean())
    assert board.loc[ORACLE, "human n"] == 6                 # re-ratings replaced, not added
    assert board.loc[ORACLE, "human α"] == pytest.approx(
        krippendorff_alpha([human_means["ann"], human_means["bob"]], "ordinal"))
    assert pd.isna(board.loc[P5, "human ↑"]) and board.loc[P5, "human n"] == 0
    assert judges.loc[("judge_gemini", "human"), "n"] == 6
    human = out.tables["human"].set_index("run")
    assert human.loc["all runs", "raters"] == 2 and human.loc["all runs", "ratings"] == 12
    assert human.loc["all runs", "scenes"] == 6


def test_parameter_recovery_and_paired_bootstrap(study):
    out = study["out"]
    params = out.tables["param_recovery"].set_index("run")
    assert params.loc[ORACLE, "gravity n"] >= 1
    assert params.loc[ORACLE, "gravity MAE ↓ [m/s²]"] < 0.05      # the oracle states the truth
    assert params.loc[STATIC, "gravity n"] == 0                   # no spec, nothing to recover
    boot = out.tables["bootstrap"]
    row = boot[(boot["metric"] == "psnr ↑") & boot["A"].isin([ORACLE, STATIC])
               & boot["B"].isin([ORACLE, STATIC])].iloc[0]
    assert row["n common"] == 3 and row["better"] == ORACLE
    assert (row["CI low"] > 0) == (row["A"] == ORACLE)


def test_figures_are_real_png_and_svg(study):
    out = study["out"]
    assert {"boxplot_psnr", "boxplot_flow_epe_dis", "radar"} <= set(out.figures)
    for name, (png, svg) in out.figures.items():
        with Image.open(png) as image:
            assert image.format == "PNG" and image.width > 300 and image.height > 200, name
        assert ET.parse(svg).getroot().tag.endswith("svg")
    md = out.markdown
    assert "![radar](radar.png)" in md and "## Leaderboard (headline metrics)" in md


def test_the_analyse_command_prints_and_writes(study):
    home, out = study["home"], study["root"] / "cli"
    proc = run_cli("analyse", str(home / "runs"), "-o", str(out), "--study", "cross_engine",
                   "--metrics", "psnr,flow_epe_dis", home=home, env={"COLUMNS": "80"})
    text = proc.stdout
    assert "Leaderboard" in text and ORACLE in text
    assert text.count("Spearman ρ over scenes") == 1  # one table: a row per metric
    # five runs make ten pairs: too wide for 80 columns, so the pairs go on over more tables,
    # each with the metric's name first; no line is wider than the terminal
    assert re.search(r"^│ psnr\b", text, re.M) and re.search(r"^│ flow_epe_dis\b", text, re.M)
    assert "ρ 4–5" in text and max(len(ln.rstrip()) for ln in text.splitlines()[:-1]) <= 80
    assert str(out.resolve()) in text.replace("\n", "")
    for name in ("leaderboard.csv", "spearman_psnr.tex", "spearman_mean.md", "boxplot_psnr.svg",
                 "analysis.md", "analysis.json"):
        assert (out / name).is_file(), name
    assert not (out / "judges.csv").exists()          # not part of the cross-engine study


def test_the_analyse_command_says_what_is_wrong_in_one_line(study, capsys):
    from visphy_core.cli.main import main

    assert main(["analyse", str(study["root"] / "replies")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "no finished run directory here" in err
    assert err.count("\n") == 1
    assert main(["analyse", str(study["home"] / "runs"), "--metrics", "psnr,nope", "-o",
                 str(study["root"] / "x")]) == 2
    assert "unknown metric column(s) nope" in capsys.readouterr().err
