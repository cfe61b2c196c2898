"""What a run and a study log to MLflow, computed from a summary and rows (no MLflow store here:
tests/test_mlflow_rest.py checks a real server)."""

from __future__ import annotations

import os

import enum
import json

import pytest
from omegaconf import OmegaConf

from visphy_core.results.row import SceneResult
from visphy_core.study.finish import comparison_rows
from visphy_core.tracking import (
    family_means,
    headline_metrics,
    run_params,
    scene_table,
    summary_metrics,
)


def _mean(ok, with_fb=None) -> dict:
    return {"mean_model_success": ok, "n_model_success": 1,
            "mean_with_fallbacks": ok if with_fb is None else with_fb, "n_with_fallbacks": 2}


SUMMARY = {
    "headline": {"metric": "physics_score", "mean": 0.4, "ci": [0.1, 0.7], "n": 2,
                 "mean_model_success": 0.5},
    "metrics": {"physics_score": _mean(0.5, 0.4), "psnr": _mean(30.0, 25.0),
                "psnr.aligned": _mean(31.0), "ssim": _mean(0.9), "rouge_l": _mean(0.3),
                "norm.psnr": _mean(0.6, 0.5), "norm.ssim": _mean(5.0),  # clipped to 1
                "norm.track_pos_err": _mean(0.2, 0.25), "norm.mse": _mean(None, None)},
    "metric_info": {"psnr": {"family": "pixel"}, "ssim": {"family": "pixel"},
                    "mse": {"family": "pixel"}, "track_pos_err": {"family": "physics"},
                    "rouge_l": {"family": "text"}},
    "n_scenes": 2, "model_success_rate": 0.5, "fallbacks": 1,
}


def test_family_means_average_the_clipped_normalised_means_over_scored_scenes():
    # pixel: norm.psnr 0.5 (with fallbacks), norm.ssim 5.0 clipped to 1; norm.mse has no mean;
    # text has no normalised column (raw means in different units are not averaged)
    assert family_means(SUMMARY) == {"family.physics": pytest.approx(0.25),
                                     "family.pixel": pytest.approx(0.75)}
    assert family_means(SUMMARY, clip=(-1.0, 3.0))["family.pixel"] == pytest.approx(1.75)
    assert family_means({"metrics": {"psnr": _mean(30.0)}, "metric_info": {}}) == {}


def test_headline_metrics_and_the_per_metric_means():
    head = headline_metrics(SUMMARY)
    assert head == {"headline": 0.4, "headline.lo": 0.1, "headline.hi": 0.7, "headline.n": 2.0,
                    "family.physics": pytest.approx(0.25), "family.pixel": pytest.approx(0.75),
                    "n_scenes": 2.0, "model_success_rate": 0.5, "fallbacks": 1.0}
    metrics = summary_metrics(SUMMARY)
    assert metrics.items() >= head.items()
    assert metrics["psnr"] == 30.0 and metrics["psnr_with_fallbacks"] == 25.0
    assert metrics["norm.psnr_with_fallbacks"] == 0.5
    # a derived pairing: its model-success mean only; no count columns, no per-scene steps
    assert metrics["psnr.aligned"] == 31.0 and "psnr.aligned_with_fallbacks" not in metrics
    assert not [k for k in metrics if k.endswith("_n") or k.startswith("scene/")]
    assert "headline" not in headline_metrics({"headline": None, "metrics": {}})


class Style(enum.Enum):
    exact = "exact"


def test_params_are_the_keys_that_tell_runs_apart():
    cfg = OmegaConf.create({
        "model": {"name": "gpt5", "model_id": "gpt-5", "price": {"input_usd_per_mtok": 1.0},
                  "max_output_tokens": 32768, "style": Style.exact},
        "engine": {"name": "blender", "disk_mb": 512, "denoise": True},
        "dataset": {"name": "visphybench", "split": "test", "limit": None},
        "prompt": {"frames": [1, 10], "forecast_only": False},
        "run": {"seed": 0, "retry": False}, "judge": {"gemini": {"name": "gemini"}}})
    params = run_params(cfg, swept=["run.retry", "model", "hydra/launcher"])
    assert params == {"model.name": "gpt5", "model.model_id": "gpt-5", "model.style": "exact",
                      "engine.name": "blender",
                      "dataset.name": "visphybench", "dataset.split": "test",
                      "prompt.frames": "1,10", "prompt.forecast_only": False, "run.seed": 0,
                      "run.retry": False, "model": "gpt5", "judge": "gemini"}
    assert run_params(OmegaConf.create({"judge": {}}))["judge"] == "none"


def test_the_scene_table_has_a_row_per_scene_and_a_column_per_score():
    rows = [SceneResult("a", "2d", None, model_success=True, system_success=True, attempts=1,
                        scores={"psnr": 30.0, "ssim": 0.9, "norm.psnr": 0.5}),
            SceneResult("b", "2d", None, system_success=True, fallback=True, attempts=2,
                        failure_class="render_error", scores={"psnr": 20.0})]
    table = scene_table(rows, ["psnr", "ssim", "norm.psnr"])
    # no dot in a column's name: MLflow's table view would read it as a nested field
    assert list(table.columns) == ["scene_id", "outcome", "psnr", "ssim", "norm_psnr"]
    assert list(table["outcome"]) == ["ok", "fallback (render_error)"]
    assert table["psnr"].tolist() == [30.0, 20.0]
    assert table["ssim"].isna().tolist() == [False, True]  # undefined: an empty cell


def test_a_studys_comparison_table_has_a_row_per_job(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps(SUMMARY))
    (run / "config.yaml").write_text("metrics: {headline: {clip: [-1.0, 3.0]}}\n")
    jobs = [{"num": 0, "label": "model=a engine=p5", "status": "completed", "run_dir": str(run),
             "run_status": "finished", "mlflow_run_id": "r0",
             "overrides": ["model=a", "engine=p5", "dataset.limit=2"]},
            {"num": 1, "label": "model=b engine=p5", "status": "failed",
             "overrides": ["model=b", "engine=p5", "dataset.limit=2"]}]
    done, failed = comparison_rows(jobs, {"model": "a,b", "engine": "p5"})
    assert done["model"] == "a" and done["engine"] == "p5" and "dataset.limit" not in done
    assert done["status"] == "finished" and done["mlflow_run_id"] == "r0"
    assert done["headline"] == 0.4 and done["headline.lo"] == 0.1
    assert done["family.pixel"] == pytest.approx(1.75)  # the run's own clip
    assert done["model_success_rate"] == 0.5 and "psnr" not in done
    assert failed == {"job": 1, "label": "model=b engine=p5", "model": "b", "engine": "p5",
                      "status": "failed", "mlflow_run_id": None}


def test_mlflow_telemetry_is_off_unless_the_user_turns_it_on():
    """Its thread races the run's threads over the environment (and calls out of machines
    that are often offline); a user's own setting wins."""
    import subprocess
    import sys

    code = ("import os, visphy_core.tracking, mlflow; "
            "print(os.environ['MLFLOW_DISABLE_TELEMETRY'])")
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_DISABLE_TELEMETRY"}
    off = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    on = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                        env=dict(env, MLFLOW_DISABLE_TELEMETRY="false"))
    assert off.stdout.strip() == "true" and on.stdout.strip() == "false"
