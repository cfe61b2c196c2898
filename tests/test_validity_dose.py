"""The extended validity study: the dose series (`visphy_plugins.studies.validity.dose`), the goals'
summary and its discriminative power (`goals`), and a small study on the ``mini`` split's 2D scenes
writing the summary JSON (``benchmarks/validity_study.py --order``'s own function, one cheap
metric, a few variants, the flow baseline stubbed: seconds)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from mini_templates import mini_specs

from visphy_core.api.metrics import HIGHER, LOWER
from visphy_plugins.studies.validity import clips as vc
from visphy_plugins.studies.validity import dose as vd
from visphy_plugins.studies.validity import goals as vg
from visphy_plugins.studies.validity import interventions as vi
from visphy_plugins.studies.validity import order as vo
from visphy_plugins.studies.validity import study as vs

REPO = Path(__file__).resolve().parents[1]


def _spec(start: str) -> dict:
    return next(s for s in mini_specs() if s["description"].startswith(start))


@pytest.fixture(scope="module")
def fall() -> vc.Truth:
    """The red ball falls freely (from rest) and clips a purple box's corner."""
    return vc.Truth.of(_spec("red ball falls freely"), vc.Renderer2D())


@pytest.fixture(scope="module")
def thrown() -> vc.Truth:
    """A thrown red ball knocks a green ball off a gray box."""
    return vc.Truth.of(_spec("thrown"), vc.Renderer2D())


# ------------------------------------------------------------------------------- doses
def test_dose_clips_depart_further_from_the_truth_as_the_dose_grows(fall, thrown):
    skipped: dict[str, str] = {}
    clips = list(vd.dose_clips(fall, None, skipped))
    by = {}
    for c in clips:
        assert c.kind == vc.DOSE and c.frames.shape == fall.frames.shape
        by.setdefault(c.series, []).append(c)
    for name in ("gravity", "playback"):
        doses = [c.dose for c in by[name]]
        devs = [c.deviation for c in by[name]]
        assert doses == sorted(doses) and len(doses) == 3, name
        assert all(a < b for a, b in zip(devs, devs[1:])), (name, devs)
        assert devs[0] >= vd.DOSE_MIN_PX
    assert [c.name for c in by["gravity"]] == ["gravity_x0.9", "gravity_x0.75", "gravity_x0.5"]
    assert [c.dose for c in by["playback"]] == pytest.approx([0.1, 0.2, 0.33])
    # a ball at rest has no launch to turn; PHYRE's restitution 0.2 − 0.3 clamps to 0 like − 0.2
    assert skipped["dose:launch"].startswith("the action body (red_ball) starts at rest")
    assert skipped["dose:restitution-0.3"].endswith("the clip equals the previous dose's")
    launch = [c for c in vd.dose_clips(thrown, vd.series_named(["launch"]))]
    assert [c.name for c in launch] == ["launch+5", "launch+10", "launch+20"]
    assert all(c.deviation > vi.VISIBLE_PX for c in launch)


def test_the_launch_turns_toward_the_vertical_and_keeps_the_speed():
    for v, deg in (((3.0, 4.0), 10.0), ((-3.0, 4.0), 10.0), ((5.0, 0.0), 20.0)):
        out = vd.turned(np.array(v), deg, "2d")
        assert np.linalg.norm(out) == pytest.approx(np.linalg.norm(v))
        elevation = math.degrees(math.atan2(v[1], abs(v[0])))
        assert math.degrees(math.atan2(out[1], abs(out[0]))) == pytest.approx(elevation + deg)
    v3 = np.array([2.0, 1.0, -2.0])
    out = vd.turned(v3, 20.0, "3d")
    assert np.linalg.norm(out) == pytest.approx(3.0)
    assert math.degrees(math.asin(out[1] / 3.0)) == pytest.approx(
        math.degrees(math.asin(1.0 / 3.0)) + 20.0)
    assert out[0] / out[2] == pytest.approx(v3[0] / v3[2])  # same heading
    # the spec edit: the action body's velocity only
    thrown = vc.Truth(_spec("thrown"), np.zeros((1, 5, 3)), np.zeros((1, 2, 2, 3), np.uint8),
                      _Poses())
    spec, _ = vd.launch_dose(thrown, 10.0)
    v0 = next(b for b in thrown.spec["bodies"] if b["id"] == "red_ball")["velocity"]
    v1 = next(b for b in spec["bodies"] if b["id"] == "red_ball")["velocity"]
    assert np.hypot(v1["vx_px_s"], v1["vy_px_s"]) == pytest.approx(
        np.hypot(v0["vx_px_s"], v0["vy_px_s"]))
    assert [b for b in spec["bodies"] if b["id"] != "red_ball"] == \
        [b for b in thrown.spec["bodies"] if b["id"] != "red_ball"]


class _Poses:
    def simulate(self, spec):
        return np.zeros((1, len(spec["bodies"]), 3))


def test_slower_playback_interpolates_the_truths_own_steps(fall):
    steps, frame_steps = fall.steps
    assert np.allclose(vd.slowed_poses(fall, 1.0), fall.poses)
    half = vd.slowed_poses(fall, 0.5)
    assert np.array_equal(half[0], fall.poses[0])                  # frame 0 unchanged
    # frame 2 at factor 0.5: step 1 + (121 − 1) / 2 = 61, frame 1's own step
    assert frame_steps[0] == 1 and frame_steps[2] == 121
    assert np.allclose(half[2], fall.poses[1])
    # 3D: a quaternion blended along the shorter arc and normalised
    q = np.array([[[0, 0, 0, 0, 0, 0, 1.0]], [[2, 0, 0, 0, 0, -math.sin(0.1), -math.cos(0.1)]]])
    truth3 = vc.Truth({}, q[[0, 1]], np.zeros((2, 1, 1, 3), np.uint8), None,
                      (q, np.array([0, 1])))
    mid = vd.slowed_poses(truth3, 0.5)[1, 0]
    assert mid[0] == pytest.approx(1.0) and np.linalg.norm(mid[3:]) == pytest.approx(1.0)
    assert mid[6] > 0.99                                           # not through zero


def test_monotone_means_spearman_at_most_minus_point_nine_ties_averaged():
    assert vd.spearman([0, 1, 2, 3], [1.0, 0.9, 0.8, 0.5]) == pytest.approx(-1.0)
    tie = vd.spearman([0, 1, 2, 3], [1.0, 1.0, 0.8, 0.5])         # the truth and dose 1 clipped
    assert tie == pytest.approx(-0.9487, abs=1e-4) and vd.monotone(tie)
    swap = vd.spearman([0, 1, 2, 3], [1.0, 0.8, 0.9, 0.5])
    assert swap == pytest.approx(-0.8) and not vd.monotone(swap)
    assert vd.spearman([0, 1, 2], [1.0, 1.0, 1.0]) is None and not vd.monotone(None)
    assert vd.spearman([0, 1], [1.0, 0.5]) is None
    assert vd.spearman([0, 1, 2], [math.inf, 3.0, 1.0]) == pytest.approx(-1.0)


def _clip(name, kind, headline, scores=None, **kw):
    return vc.ClipScore(name, kind, "", scores or {}, headline, **kw)


def _result(sid, right, wrong, doses, truth=1.0, static=0.0, flow=0.1):
    clips = [_clip(n, vc.RIGHT, v) for n, v in right.items()]
    clips += [_clip(n, vc.WRONG, v, deviation=px) for n, (v, px) in wrong.items()]
    clips += [_clip("static", vc.STATIC, static), _clip("flow_extrapolate", vc.FLOW, flow)]
    dose = [_clip(f"{s}{d}", vc.DOSE, v, deviation=px, series=s, dose=d)
            for s, points in doses.items() for d, v, px in points]
    return vc.SceneOrder(sid, "2d", clips, {}, {}, {}, 1.0, _clip("truth", vc.TRUTH, truth),
                         dose)


def test_the_goals_summary_counts_scenes_restyles_drops_and_series():
    a = _result("a", {"pale": 0.98, "swapped": 0.7},
                {"gravity_x2": (0.5, 40.0), "friction+0.4": (0.95, 5.0)},
                {"gravity": [(0.1, 0.9, 30.0), (0.25, 0.8, 60.0), (0.5, 0.6, 90.0)],
                 "restitution": [(0.1, 1.0, 0.5), (0.2, 1.0, 1.0)]})   # hardly moves: no case
    b = _result("b", {"pale": 0.96, "swapped": 0.9}, {"gravity_x2": (0.3, 25.0)},
                {"gravity": [(0.1, 0.7, 30.0), (0.25, 0.8, 60.0), (0.5, 0.6, 90.0)]})
    scores = vg.score_summary([a, b], [])["headline"]
    # a: the 5-px friction clip does not count; every (i) > gravity > both baselines
    assert scores["strict"] == {"scenes": 2, "ordered": 2, "share": 1.0}
    assert scores["strict_any_px"]["ordered"] == 1            # a: pale 0.98 > friction 0.95 ok,
    inv = scores["invariance"]                                 # swapped 0.7 < 0.95 not
    assert inv["per_restyle"]["pale"]["median_abs"] == pytest.approx(0.03)
    assert inv["worst"] == "swapped" and inv["max_median"] == pytest.approx(0.2)
    drop = scores["physics_drop"]
    assert drop["per_intervention"] == {"gravity_x2": {"median": pytest.approx(0.6),
                                                       "scenes": 2}}
    mono = scores["monotone"]
    assert (mono["cases"], mono["monotone"], mono["scenes_monotone"]) == (2, 1, 1)
    assert mono["per_series"]["gravity"]["mean_rho"] == pytest.approx((-1.0 - 0.8) / 2)
    assert scores["goals_met"] == {"strict": True, "invariance": False, "physics_drop": True,
                                   "monotone": False}
    rows = vg.scene_rows([a, b])
    assert rows[0]["worst_restyle_name"] == "swapped" and rows[0]["monotone"] == 1.0
    assert rows[1]["smallest_drop"] == pytest.approx(0.7) and rows[1]["monotone"] == 0.0


def test_discriminative_power_is_the_bootstrap_half_width_of_a_mean_difference():
    rng = np.random.default_rng(1)
    d = rng.normal(0.0, 0.1, size=400)
    w = vg.discriminative_power(d, n_scenes=49)
    assert w == pytest.approx(1.96 * 0.1 / math.sqrt(49), rel=0.15)
    assert vg.discriminative_power(d, n_scenes=209) == pytest.approx(
        w * math.sqrt(49 / 209), rel=0.15)
    # paired: a constant gap between the two is the difference, not noise
    a = rng.normal(0.5, 0.2, size=60)
    assert vg.discriminative_power(a, a - 0.3) == pytest.approx(0.0, abs=1e-12)
    assert vg.discriminative_power([1.0, None, 2.0], [0.5, 0.1, None]) is None
    via_sd = vg.discriminative_power([], sd=[0.1] * 30, n_scenes=49)
    assert via_sd == pytest.approx(1.96 * math.sqrt(2) * 0.1 / 7, rel=0.15)


# -------------------------------------------------------------------- the study on mini
def test_a_small_study_on_the_mini_split_writes_the_summary(tmp_path, monkeypatch):
    """Two 2D scenes of the ``mini`` split (the shipped catalogue, nothing rendered ahead),
    one cheap metric, two restyles, two interventions and the gravity series; the flow
    baseline's DIS extrapolation (seconds a scene) stands in as the middle frame held."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    import validity_study

    from visphy_core.api.registry import get_registry
    from visphy_plugins.datasets.visphybench.build import shipped_catalogue

    monkeypatch.setattr(vs, "flow_clip", lambda frames, fps: np.repeat(
        frames[len(frames) // 2:len(frames) // 2 + 1], len(frames), axis=0))
    catalogue = shipped_catalogue(0)
    specs = validity_study.split_specs(catalogue, "mini", ("2d",), 2)
    assert [s["dim"] for s in specs] == ["2d", "2d"]
    metrics = vs.frame_metrics([get_registry().get("metrics", "spatiotemporal_iou_tol")])
    summary, checkpoint = tmp_path / "validity" / "summary.json", tmp_path / "scenes.jsonl"
    kw = dict(metrics=metrics, variants=["pale", "swapped", "gravity_x0.5", "remove",
                                         "gravity"],
              summary=summary, meta={"command": "test", "machine": {"cores": 2}})
    result = validity_study.order_study(specs, ("2d",), str(checkpoint), False, **kw)
    data = json.loads(summary.read_text())
    assert data["command"] == "test" and data["machine"] == {"cores": 2}
    assert data["n_scenes"] == 2 and data["scene_ids"] == [s["scene_id"] for s in specs]
    assert data["wall_s"] > 0 and data["scored_this_run"] == 2
    assert set(data["variants"]["right"]) <= {"pale", "swapped"}
    assert data["variants"]["series"] == ["gravity"]
    assert data["clips"]["dose"] >= 4 and data["goals"]["min_px"] == 20.0
    assert set(data["scores"]) == {"headline", "spatiotemporal_iou_tol"}
    for row in data["scores"].values():
        assert set(row) >= {"strict", "means", "monotone", "invariance", "physics_drop",
                            "goals_met"}
        assert row["strict"]["scenes"] <= 2 and row["monotone"]["per_series"].keys() <= {
            "gravity"}
        assert row["invariance"]["per_restyle"]["pale"]["scenes"] == 2
    assert [r["scene"] for r in data["scenes"]] == data["scene_ids"]
    assert set(data["scenes"][0]) >= {"strict", "means", "monotone", "worst_restyle",
                                      "smallest_drop"}
    power = data["discriminative_power"]["right"]["n_scenes"]
    assert set(power) == {"2", "49", "209"} and power["49"]["pairs"] == 0  # two scenes only
    # the checkpoint holds both scenes: a rerun scores nothing and summarises the same
    assert len(checkpoint.read_text().splitlines()) == 2
    again = validity_study.order_study(specs, ("2d",), str(checkpoint), False, **kw)
    assert again["scored_this_run"] == [] and again["goals"]["scores"] == data["scores"]
    assert result["results"][0]["doses"] and result["results"][0]["truth"]["name"] == "truth"
    # what was asked is kept: a rerun with other variants scores the scenes again
    assert vc.SceneOrder.from_json(result["results"][0]).options["series"] == ["gravity"]


def test_a_headline_from_other_metrics_is_recomputed_from_the_stored_twin():
    metrics = [_Metric("iou", HIGHER), _Metric("err", LOWER)]
    clips = [_clip("pale", vc.RIGHT, None, {"iou": 0.9, "err": 1.0}),
             _clip("static", vc.STATIC, None, {"iou": 0.0, "err": 10.0})]
    res = vc.SceneOrder("s", "2d", clips, {}, {"iou": 0.8, "err": 2.0}, {}, 0.0,
                        _clip("truth", vc.TRUTH, None, {"iou": 1.0, "err": 0.0}),
                        [_clip("g", vc.DOSE, None, {"iou": 0.4, "err": 6.0}, series="gravity",
                               dose=0.1)])
    from visphy_core.api.scoring import Headline

    (out,) = vo.rescored_headline([res], metrics, Headline(components=("err",),
                                                                    ceiling="twin"))
    assert out.clips[0].headline == pytest.approx(1.0)      # (10 − 1) / (10 − 2), clipped
    assert out.doses[0].headline == pytest.approx(0.5) and out.truth.headline == 1.0


class _Metric:
    def __init__(self, name, direction):
        self.name, self.direction = name, direction
        self.score_range = (0.0, 1.0) if direction == HIGHER else (0.0, math.inf)
