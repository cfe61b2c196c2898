"""`visphy export`: a run's scores as one tidy table (`visphy_core.results.tidy`), from a run
directory written by hand (a real run's rows, without rendering anything)."""

from __future__ import annotations

import json

import pandas as pd

from visphy_core.cli.main import main
from visphy_core.results.row import SceneResult
from visphy_core.results.tidy import FIELDS, decompose_column, score_column, tidy_scores

#: Every shape of score column a run writes (`visphy_core.results.columns`).
COLUMNS = ("psnr", "psnr.aligned", "paper.psnr", "align.offset", "align.err",
           "paper.align.offset", "norm.psnr", "norm.psnr.aligned", "spec.psnr",
           "spec.psnr.aligned", "spec.paper.psnr", "spec.align.err", "spec.paper.align.err",
           "spec.norm.psnr", "judge_gemini", "physics_score", "spec.physics_score")


def _write_run(tmp_path):
    ok = SceneResult(scene_id="vpb3-s0-2d-t001-v00", dim="2d", difficulty="easy",
                     model_success=True, system_success=True, attempts=1,
                     scores={c: float(i) for i, c in enumerate(COLUMNS)})
    ok.scores["judge_gemini"] = None
    ok.unavailable["judge_gemini"] = "GEMINI_API_KEY not set"
    failed = SceneResult(scene_id="vpb3-s0-3d-t004-v02", dim="3d", difficulty="hard",
                         attempts=2, failure_class="runtime_error",
                         scores={"spec.psnr": 12.5}, unavailable={"spec.norm.psnr": "no twin"})
    run = tmp_path / "2026-01-01_00-00-00_m_threejs_abcd"
    run.mkdir()
    (run / "results.jsonl").write_text(
        "".join(json.dumps(r.row()) + "\n" for r in (ok, failed)))
    (run / "manifest.json").write_text(json.dumps(
        {"status": "finished", "scenes": [ok.scene_id, failed.scene_id]}))
    (run / "summary.json").write_text(json.dumps(
        {"status": "finished", "headline": {"metric": "physics_score"},
         "metric_info": {"psnr": {"direction": "higher"}}}))
    (run / "config.yaml").write_text(json.dumps(
        {"model": {"name": "m"}, "engine": {"name": "threejs"},
         "dataset": {"name": "visphybench", "split": "sub"}}))
    return run


def test_every_column_shape_decomposes_and_composes_back():
    spelt = {c: decompose_column(c, "physics_score") for c in COLUMNS}
    assert all(score_column(*s) == c for c, s in spelt.items())
    assert spelt["spec.norm.psnr"] == ("metric", "psnr", "visphy", "spec", True)
    assert spelt["norm.psnr.aligned"] == ("metric", "psnr", "aligned", "program", True)
    assert spelt["paper.align.offset"] == ("alignment", "offset", "paper", "program", False)
    assert spelt["align.err"] == ("alignment", "err", "aligned", "program", False)
    assert spelt["judge_gemini"] == ("judge", "gemini", None, "program", False)
    assert spelt["spec.physics_score"].kind == "headline"


def test_every_scene_has_every_column_and_a_failed_one_says_why(tmp_path):
    table = tidy_scores(_write_run(tmp_path))
    assert list(table.columns) == list(FIELDS)
    assert len(table) == 2 * len(COLUMNS)            # the failed scene is not dropped
    assert set(table["template"]) == {"t001", "t004"}
    assert set(table["dataset"]) == {"visphybench"} and set(table["split"]) == {"sub"}
    failed = table[table["scene_id"] == "vpb3-s0-3d-t004-v02"].set_index("column")
    assert failed.loc["spec.psnr", "value"] == 12.5   # S is scored without a clip
    assert failed.loc["spec.norm.psnr", "unavailable"] == "no twin"
    assert failed.loc["psnr", "unavailable"] == "no clip (runtime_error)"
    assert pd.isna(failed.loc["psnr", "value"])
    ok = table[table["scene_id"] == "vpb3-s0-2d-t001-v00"].set_index("column")
    assert ok.loc["judge_gemini", "unavailable"] == "GEMINI_API_KEY not set"
    assert ok.loc["paper.psnr", "value"] == 2.0 and pd.isna(ok.loc["paper.psnr", "unavailable"])
    assert ok.loc["align.err", "direction"] == "lower"
    # the counts a groupby gives are the run's denominators: non-null over every scene
    counts = table.groupby("column")["value"].count()
    assert counts["psnr"] == 1 and counts["spec.psnr"] == 2


def test_cli_csv_and_parquet_hold_the_same_table(tmp_path):
    run = _write_run(tmp_path)
    for fmt in ("csv", "parquet"):
        assert main(["export", str(run), "--format", fmt, "-o", str(tmp_path / f"t.{fmt}")]) == 0
    csv = pd.read_csv(tmp_path / "t.csv", keep_default_na=False, na_values=[""])
    parquet = pd.read_parquet(tmp_path / "t.parquet")
    pd.testing.assert_frame_equal(csv[list(FIELDS)], parquet, check_dtype=False)


def test_cli_a_missing_run_is_one_line(capsys):
    assert main(["export", "/nonexistent/run"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err
