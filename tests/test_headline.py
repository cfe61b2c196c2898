"""The headline physics score: still clip at exactly 0, ground truth near 1, on generated and
original-layout datasets; summary, rows, headline.json and the console all carry it."""

from __future__ import annotations

import json
import math
import shutil

import pandas as pd
import pytest

from conftest import run_cli
from visphy_core.api.metrics import HIGHER, LOWER
from visphy_core.scoring.headline import (
    DEFAULT_CEILING,
    DEFAULT_COMPONENTS,
    Headline,
    bootstrap_ci,
    component,
    ideal,
    scene_headline,
)

COMPONENTS = "metrics.names=[psnr,spatiotemporal_iou_tol,weighted_spatial_iou_tol]"
QUIET = ("tracking=none", "run.progress=false", "metrics.spec_track=false")


class _M:
    def __init__(self, name, direction, score_range):
        self.name, self.direction, self.score_range = name, direction, score_range


def test_components_are_normalised_between_the_still_clip_and_the_ceiling_and_clipped():
    assert component(0.5, 0.0, 1.0, HIGHER, (-1, 1)) == (0.5, None)
    assert component(10.0, 40.0, 0.0, LOWER, (-1, 1)) == (0.75, None)
    assert component(90.0, 40.0, 0.0, LOWER, (-1, 1))[0] == -1.0      # clipped below
    assert component(-1.0, 40.0, 0.0, LOWER, (-1, 1))[0] == 1.0        # clipped above
    value, why = component(3.0, 2.0, 2.0, LOWER, (-1, 1))               # anchors equal
    assert value is None and "not better than the still clip" in why
    assert component(None, 0.0, 1.0, HIGHER, (-1, 1)) == (None, "no value")


def test_the_ceiling_is_the_twin_where_there_is_one_else_the_ideal_value():
    iou, err = _M("iou", HIGHER, (0.0, 1.0)), _M("err", LOWER, (0.0, math.inf))
    assert ideal(iou) == 1.0 and ideal(err) == 0.0
    head = Headline(name="h", components=("iou", "err"), ceiling="twin")
    value, details = scene_headline(head, [iou, err], {"iou": 0.8, "err": 5.0},
                                    {"iou": 0.0, "err": 50.0}, {"err": 1.0})
    parts = details["components"]
    assert parts["iou"]["ceiling_from"] == "ideal" and parts["iou"]["normalised"] == 0.8
    assert parts["err"]["ceiling_from"] == "twin"
    assert parts["err"]["normalised"] == pytest.approx(45 / 49)
    assert value == pytest.approx((0.8 + 45 / 49) / 2)
    # a component the scene does not define is left out of the mean, with its reason
    value, details = scene_headline(head, [iou, err], {"iou": None, "err": 5.0},
                                    {"iou": 0.0, "err": 50.0}, {})
    assert value == pytest.approx(0.9) and details["components"]["iou"]["undefined"]
    # metrics.headline.ceiling=ideal: the twin is not read, every 1 is the metric's best value
    ideal_head = Headline(name="h", components=("iou", "err"), ceiling="ideal")
    value, details = scene_headline(ideal_head, [iou, err], {"iou": 0.8, "err": 5.0},
                                    {"iou": 0.0, "err": 50.0}, {"err": 1.0, "iou": 0.5})
    assert {p["ceiling_from"] for p in details["components"].values()} == {"ideal"}
    assert value == pytest.approx((0.8 + 45 / 50) / 2) and details["ceiling"] == "ideal"


def test_the_bootstrap_interval_is_seeded_and_brackets_the_mean():
    vals = [0.1, 0.5, 0.9, 0.3, 0.7]
    lo, hi = bootstrap_ci(vals)
    assert lo < sum(vals) / len(vals) < hi and bootstrap_ci(vals) == [lo, hi]
    assert bootstrap_ci([0.5]) is None


def _run(home, *args):
    proc = run_cli(*args, COMPONENTS, *QUIET, home=home)
    run_dir = max((home / "runs").iterdir(), key=lambda p: p.stat().st_mtime)
    return proc, run_dir, json.loads((run_dir / "summary.json").read_text())


def test_the_oracle_scores_about_one_and_the_still_clip_exactly_zero(visphy_home):
    proc, run_dir, summary = _run(visphy_home, "model=oracle", "dataset=mini")
    head = summary["headline"]
    assert head["metric"] == "physics_score" and head["mean"] > 0.9 and len(head["ci"]) == 2
    assert head["n"] == 4 and head["small_sample"] is True
    assert "headline physics_score" in proc.stdout
    rows = pd.read_parquet(run_dir / "results.parquet")
    assert (rows["score_physics_score"] > 0.8).all()
    details = json.loads(next((run_dir / "scenes").glob("*/headline.json")).read_text())
    assert set(details["components"]) == set(DEFAULT_COMPONENTS)
    assert {p["ceiling_from"] for p in details["components"].values()} == {DEFAULT_CEILING}
    # the static baseline's clip is the first key frame held, encoded by the baseline itself:
    # the floor's own clip up to the codec's rounding
    _, run_dir, summary = _run(visphy_home, "model=static", "dataset=mini")
    assert summary["headline"]["mean"] == pytest.approx(0.0, abs=1e-3)
    rows = pd.read_parquet(run_dir / "results.parquet")
    assert rows["score_physics_score"].abs().max() < 1e-3


def test_the_headline_needs_no_spec_on_the_original_layout(tmp_path):
    """Original layout (no spec, no twin): the still clip scores 0, the ground truth replayed
    as a video ~1, with the ideal values as ceilings."""
    from visphy_plugins.datasets.tiny import make_tiny_dataset

    root = make_tiny_dataset(tmp_path / "data", 2)
    videos = tmp_path / "videos"
    shutil.copytree(root / "sub" / "videos", videos)
    home = tmp_path / "home"
    base = ("dataset=original", f"dataset.root={root}")
    _, run_dir, summary = _run(home, "model=replay", f"model.source={videos}",
                               "model.output=video", *base)
    assert summary["headline"]["mean"] > 0.9
    details = json.loads(next((run_dir / "scenes").glob("*/headline.json")).read_text())
    assert {p["ceiling_from"] for p in details["components"].values()
            if p.get("normalised") is not None} == {"ideal"}
    _, _, summary = _run(home, "model=static", *base)
    assert summary["headline"]["mean"] == pytest.approx(0.0, abs=1e-3)
