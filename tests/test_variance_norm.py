"""Variance-normalised scores: the ground truth's twin (an imperceptibly nudged re-simulation)
is the ceiling, the frozen first frame the floor (visphy_core.scoring.normalisation)."""

from __future__ import annotations

import copy
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_spec_track import _reply_of, _reply_text

from visphy_core.api.metrics import HIGHER, LOWER
from visphy_core.results.columns import norm_column
from visphy_core.scoring.normalisation import (
    NUDGE_M,
    NUDGE_PX,
    SPEED_JITTER,
    normalised,
    twin_scene,
    twin_spec,
)
from visphy_core.scoring.score import ScoringProtocol, score_columns


def _spec_3d() -> dict:
    body = {"id": "ball", "dynamic": True,
            "pose": {"position_m": [0.5, 1.0, -0.2], "quat": [0, 0, 0, 1]},
            "velocity": {"linear_m_s": [1.0, 2.0, 0.5], "angular_rad_s": [0.0, 0.1, 0.0]}}
    wall = {"id": "wall", "dynamic": False,
            "pose": {"position_m": [2.0, 0.5, 0.0], "quat": [0, 0, 0, 1]}}
    return {"scene_id": "x3d", "dim": "3d", "bodies": [body, wall]}


def test_the_twin_nudges_only_dynamic_bodies_by_the_stated_amounts(mini_scenes):
    spec = mini_scenes[0].spec
    twin = twin_spec(spec)
    assert twin_spec(spec) == twin                      # deterministic
    assert spec == mini_scenes[0].spec                  # the scene's spec is left alone
    moved = 0
    for before, after in zip(spec["bodies"], twin["bodies"]):
        if not before.get("dynamic"):
            assert after == before
            continue
        moved += 1
        dx = after["pose"]["x_px"] - before["pose"]["x_px"]
        assert abs(dx) == pytest.approx(NUDGE_PX)
        assert after["pose"]["y_px"] == before["pose"]["y_px"]  # never into a support
        for key in ("vx_px_s", "vy_px_s"):
            v0, v1 = before["velocity"][key], after["velocity"][key]
            assert v1 == pytest.approx(v0 * (1 + SPEED_JITTER)) or \
                v1 == pytest.approx(v0 * (1 - SPEED_JITTER))
    assert moved >= 1

    spec3 = _spec_3d()
    twin3 = twin_spec(spec3)
    p0, p1 = (np.array(s["bodies"][0]["pose"]["position_m"]) for s in (spec3, twin3))
    assert np.linalg.norm(p1 - p0) == pytest.approx(NUDGE_M)
    assert p1[1] == p0[1]                               # horizontal only
    ratio = np.array(twin3["bodies"][0]["velocity"]["linear_m_s"]) / [1.0, 2.0, 0.5]
    assert np.allclose(ratio, ratio[0]) and abs(abs(ratio[0] - 1) - SPEED_JITTER) < 1e-12
    assert twin3["bodies"][1] == spec3["bodies"][1]
    other = copy.deepcopy(spec3)
    other["scene_id"] = "another"
    assert twin_spec(other)["bodies"][0] != twin3["bodies"][0]  # seeded by the scene id


def test_the_twin_trajectory_starts_where_the_ground_truth_does_but_is_not_it(mini_scenes):
    scene = mini_scenes[0]
    gt = scene.trajectory["frame_poses"]
    twin = twin_scene(scene).trajectory["frame_poses"]
    assert twin.shape == gt.shape
    assert not np.array_equal(twin, gt)
    # frame 0: at most the nudge apart (pixels in 2D), positions only
    assert np.abs(twin[0, :, :2] - gt[0, :, :2]).max() <= NUDGE_PX + 1e-3  # float32 poses


@pytest.mark.parametrize("value, floor, ceiling, direction, expected", [
    (30.0, 20.0, 40.0, HIGHER, 0.5),
    (40.0, 20.0, 40.0, HIGHER, 1.0),
    (20.0, 20.0, 40.0, HIGHER, 0.0),
    (50.0, 20.0, 40.0, HIGHER, 1.5),     # closer than the twin: kept, not clipped
    (10.0, 20.0, 40.0, HIGHER, -0.5),    # worse than frozen: kept
    (5.0, 10.0, 0.0, LOWER, 0.5),
    (0.0, 10.0, 0.0, LOWER, 1.0),
    (12.0, 10.0, 2.0, LOWER, -0.25),
])
def test_normalised_maps_floor_to_0_and_ceiling_to_1(value, floor, ceiling, direction,
                                                    expected):
    norm, why = normalised(value, floor, ceiling, direction)
    assert why is None and norm == pytest.approx(expected)


@pytest.mark.parametrize("value, floor, ceiling, direction, reason", [
    (1.0, 5.0, 5.0, HIGHER, "not better"),          # nothing separates the anchors
    (1.0, 5.0, 4.0, HIGHER, "not better"),          # the twin drifts further than frozen
    (1.0, 2.0, 3.0, LOWER, "not better"),
    (None, 1.0, 2.0, HIGHER, "no score"),
    (float("nan"), 1.0, 2.0, HIGHER, "no score"),
    (1.0, None, 2.0, HIGHER, "undefined"),
    (1.0, 1.0, float("inf"), HIGHER, "undefined"),
])
def test_normalised_is_none_with_a_reason_when_the_anchors_do_not_separate(
        value, floor, ceiling, direction, reason):
    norm, why = normalised(value, floor, ceiling, direction)
    assert norm is None and reason in why


def test_columns_are_listed_higher_is_better_for_frame_metrics_only():
    from visphy_core.api.registry import get_registry

    reg = get_registry()
    metrics = [reg.get("metrics", n) for n in ("psnr", "track_pos_err", "rouge_l")]
    cols = dict(score_columns(metrics, ScoringProtocol(spec_track=True, variance_norm=True)))
    assert cols["norm.psnr"] == cols["norm.track_pos_err"] == HIGHER
    assert cols["spec.norm.track_pos_err"] == HIGHER
    assert "norm.rouge_l" not in cols and "spec.norm.rouge_l" not in cols
    assert "norm.psnr" not in dict(score_columns(metrics, ScoringProtocol()))
    assert norm_column("spec.ssim") == "spec.norm.ssim" and norm_column("ssim") == "norm.ssim"


@pytest.mark.slow
@pytest.mark.browser
def test_a_run_scores_the_oracle_near_1_and_the_fallback_at_exactly_0(tmp_path, mini_root,
                                                                     mini_scenes):
    """One replayed reply is the ground truth's own reference program, the other a broken
    program (fallback) with a sound S: the oracle lands near the twin, the frozen fallback at
    0 on every metric, S's spec track between."""
    from visphy_core.api.registry import get_registry
    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment

    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    # the oracle's scene: the least sensitive of the mini scenes (a chaotic scene's twin drifts
    # visibly, which is what the twin is for, but not what this test measures)
    good = min(mini_scenes, key=lambda s: s.spec["difficulty"]["features"]["sensitivity_px"])
    bad = next(s for s in mini_scenes if s is not good)
    engine = get_registry().get("engines", "threejs")()
    replies = tmp_path / "replies"
    replies.mkdir()
    try:
        (replies / f"{good.scene_id}.txt").write_text(
            _reply_text(None, engine.program_from_spec(good).source))
    finally:
        engine.close()
    s = _reply_of(bad.spec)
    s["world"]["gravity_m_s2"] = [g * 1.3 for g in s["world"]["gravity_m_s2"]]
    (replies / f"{bad.scene_id}.txt").write_text(
        _reply_text(s, "<script>throw new Error('no physics today')</script>"))
    names = ["psnr", "ssim", "track_pos_err", "event_contact_err"]
    cfg = compose([f"paths.root={home}", "tracking=none", "run.progress=false",
                   "model=replay", f"model.source={replies}", "engine=threejs",
                   f"dataset.scenes=[{good.scene_id},{bad.scene_id}]",
                   f"metrics.names=[{','.join(names)}]", "metrics.spec_track=true",
                   "metrics.variance_norm=true"])
    summary = run_experiment(cfg)
    run_dir = Path(summary["run_dir"])
    rows = {r["scene_id"]: r for r in map(json.loads, (run_dir / "results.jsonl").open())}
    ok, fb = rows[good.scene_id], rows[bad.scene_id]
    assert ok["model_success"] and fb["fallback"]

    for name in ("psnr", "ssim", "track_pos_err"):
        assert ok[f"score_norm.{name}"] > 0.9, name           # as good as the twin or better
        assert fb[f"score_norm.{name}"] == pytest.approx(0.0, abs=1e-9), name
        assert 0.0 < fb[f"score_spec.norm.{name}"] < ok[f"score_norm.{name}"], name
    anchors = json.loads((run_dir / "scenes" / good.scene_id / "normalisation.json")
                         .read_text())["anchors"]
    psnr = anchors["psnr"]
    assert psnr["ceiling"] > psnr["floor"]
    assert ok["score_norm.psnr"] == pytest.approx(
        (ok["score_psnr"] - psnr["floor"]) / (psnr["ceiling"] - psnr["floor"]))
    # the twin is imperceptible: far closer to the ground truth than the frozen clip (PSNR is
    # capped by the ground truth's published-style encoding, crf 23), its tracks sub-pixel
    assert psnr["ceiling"] > psnr["floor"] + 3 and anchors["track_pos_err"]["ceiling"] < 1.0
    assert (run_dir / "scenes" / good.scene_id / "twin_video.mp4").is_file()
    for name in names[:3]:
        m = summary["metrics"][f"norm.{name}"]
        assert m["direction"] == HIGHER and m["n_with_fallbacks"] == 2
        assert m["unavailable"] is None
    assert not math.isnan(summary["metrics"]["norm.psnr"]["mean_with_fallbacks"])


@pytest.mark.slow
def test_without_a_ground_truth_spec_the_columns_are_unavailable_with_the_reason(
        tmp_path, mini_scenes):
    """A dataset without specs (the published layout): no twin, so each norm column is
    unavailable with why — never a number — while the plain columns are scored."""
    from test_original_layout import ID_2D_A, _clip, make_split

    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment
    from visphy_core.infra.video import encode_video
    from visphy_core.spec.spec_track import SpecTrackError

    bare = copy.copy(mini_scenes[0])
    bare.__dict__["spec"] = None
    with pytest.raises(SpecTrackError, match="no ground-truth spec"):
        twin_scene(bare)

    clip = encode_video(_clip("2d", 200), tmp_path / f"{ID_2D_A}.mp4", 5)
    root = tmp_path / "original"
    make_split(root, "test", {ID_2D_A: clip}, [ID_2D_A])
    cfg = compose([f"paths.root={tmp_path / 'home'}", "tracking=none", "run.progress=false",
                   "model=static", "engine=threejs", "dataset=original",
                   f"dataset.root={root}", "dataset.split=test", "metrics.names=[psnr]",
                   "metrics.variance_norm=true", "metrics.spec_track=false"])
    summary = run_experiment(cfg)
    assert summary["metrics"]["psnr"]["n_with_fallbacks"] == 1
    norm = summary["metrics"]["norm.psnr"]
    assert norm["n_with_fallbacks"] == 0 and "no ground-truth spec" in norm["unavailable"]
