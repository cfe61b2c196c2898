"""``body_area_drift`` (plugins/metrics/area_drift.py) and the headline's penalties: bodies that
move rigidly — along the truth's path or 20 px off it, drawn larger, paler, outlined or in
swapped colours — drift no more than the truth; the flow extrapolation (pixels warped, bodies
smeared) and a body that shrinks as it moves do (measured: restyles ≤ 0.006, the offset ≤ 0.036
where the thrown ball meets the frame's edge, the flow 0.045–0.25, the shrinking bodies
0.47–0.50; ``-s -k table`` prints them). The headline subtracts the drift times its
weight, so a still clip still scores exactly 0. Clips: the hand-made mini scenes
(tests/mini_templates.py) drawn by the benchmark's rasteriser (512², 17 frames): seconds."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from mini_templates import mini_scenes

from visphy_core.api.metrics import MetricInput
from visphy_core.api.registry import get_registry
from visphy_core.scoring.alignment import unaligned
from visphy_core.scoring.headline import Headline, scene_headline
from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d
from visphy_plugins.metrics import area_drift as AD
from visphy_plugins.studies.validity.perturbation import scene_of
from visphy_plugins.studies.validity.restyles import resized_spec
from visphy_plugins.studies.validity.study import flow_clip

SCENES = (0, 1, 3)  # ramp roll, ball into jar, thrown ball
RIGID = ("truth", "grow", "pale", "swapped", "offset", "still")


def _recoloured(spec: dict, fn) -> dict:
    s = copy.deepcopy(spec)
    for b in s["bodies"]:
        b["color_rgb"] = [int(v) for v in fn(b)]
    return s


def _swapped(spec: dict) -> dict:
    dyn = [tuple(b["color_rgb"]) for b in spec["bodies"] if b.get("dynamic")]
    colours = list(dict.fromkeys(dyn))
    turn = {c: colours[(i + 1) % len(colours)] for i, c in enumerate(colours)}
    return _recoloured(spec, lambda b: turn[tuple(b["color_rgb"])] if b.get("dynamic")
                       else b["color_rgb"])


def _shrinking(spec: dict, poses: np.ndarray) -> np.ndarray:
    """Every frame drawn with the bodies scaled from 1 down to 0.6 over the clip."""
    n = len(poses)
    return np.stack([render_clip_2d(resized_spec(1.0 - 0.4 * k / (n - 1))(copy.deepcopy(spec)),
                                    poses[k:k + 1])[0] for k in range(n)])


@pytest.fixture(scope="module")
def scenes() -> list[dict]:
    made = mini_scenes()
    out = []
    for i in SCENES:
        spec, rollout = made[i]
        poses = np.asarray(rollout.frame_poses, dtype=np.float64)
        ref = render_clip_2d(spec, poses)
        moved = poses.copy()
        moving = np.linalg.norm(poses[:, :, :2] - poses[:1, :, :2], axis=-1).max(axis=0) >= 1
        moved[:, moving, 0] += 20.0
        clips = {"truth": ref.copy(),
                 "grow": render_clip_2d(resized_spec(1.1)(copy.deepcopy(spec)), poses),
                 "pale": render_clip_2d(_recoloured(spec, lambda b: [
                     round(c + 0.4 * (255 - c)) for c in b["color_rgb"]]), poses),
                 "swapped": render_clip_2d(_swapped(spec), poses),
                 "offset": render_clip_2d(spec, moved),
                 "still": np.repeat(ref[:1], len(ref), axis=0),
                 "flow": flow_clip(ref, float(spec["world"]["video_fps"])),
                 "shrinking": _shrinking(spec, poses)}
        scene = scene_of(spec)
        drift = {}
        for name, clip in clips.items():
            inp = MetricInput(scene=scene, reference=ref, generated=clip)
            drift[name] = AD.BodyAreaDrift().compute_sequence(inp, unaligned(len(ref),
                                                                             len(clip)))
        out.append({"scene": scene, "ref": ref, "clips": clips, "drift": drift})
    return out


def test_the_drift_table(scenes, capsys):
    with capsys.disabled():
        print("\nscene  " + "  ".join(f"{k:>9}" for k in scenes[0]["drift"]))
        for i, m in zip(SCENES, scenes):
            print(f"{i:>5}  " + "  ".join(f"{v:9.4f}" for v in m["drift"].values()))


@pytest.mark.parametrize("index", range(len(SCENES)))
def test_rigid_bodies_do_not_drift_however_drawn_or_wherever_they_go(scenes, index):
    d = scenes[index]["drift"]
    assert d["truth"] == 0.0 and d["still"] == 0.0
    for name in RIGID:  # the 20-px offset may meet the frame's edge or occlude another way
        assert 0.0 <= d[name] <= (0.05 if name == "offset" else 0.02), name


@pytest.mark.parametrize("index", range(len(SCENES)))
def test_smeared_or_shrinking_bodies_drift(scenes, index):
    d = scenes[index]["drift"]
    assert d["shrinking"] >= 0.1          # 0.6 of the area at the end: mean |ln| ≈ 0.25
    assert d["flow"] > max(d[name] for name in RIGID)


def test_the_drift_reads_each_clip_against_its_own_first_frame():
    areas = np.array([[100.0, 50.0], [100.0, 25.0], [100.0, 0.0]])
    # group 0 keeps its area; group 1 halves (|ln| = ln 2), then vanishes (the cap, ln 4)
    want = (2 / 3) * 0.0 + (1 / 3) * (0.0 + math.log(2) + math.log(4)) / 3
    assert AD.drift(areas) == pytest.approx(want)
    assert AD.drift(areas * 3.0) == pytest.approx(want)  # drawn larger: the same drift
    assert AD.drift(np.zeros((3, 2))) is None


def test_a_frame_a_pairing_repeats_gives_the_same_areas_each_time():
    from visphy_plugins.metrics.object_level import GenObjects

    objects = GenObjects(frame=np.array([0, 0, 1, 2]), area=np.array([10.0, 5.0, 8.0, 4.0]),
                         centroid=np.zeros((4, 2)), group=np.array([0, 1, 0, 0]),
                         group_rgb=np.zeros((2, 3)), group_area=np.zeros(2))
    got = AD.group_areas(objects, 3, np.array([0, 1, 1, 2, 2]))  # e.g. a time-warped pairing
    assert got.tolist() == [[10, 5], [8, 0], [8, 0], [4, 0], [4, 0]]


def test_registered_in_the_default_suite():
    import yaml
    from pathlib import Path

    names = yaml.safe_load((Path(__file__).resolve().parents[1] / "conf" / "metrics" /
                            "default.yaml").read_text())["names"]
    assert "body_area_drift" in names
    assert get_registry().get("metrics", "body_area_drift").direction == "lower"


def test_the_headline_subtracts_the_penalty_and_a_still_clip_stays_zero():
    reg = get_registry()
    metrics = [reg.get("metrics", "spatiotemporal_iou_tol"), reg.get("metrics", "body_area_drift")]
    head = Headline()
    assert dict(head.penalties) == {"body_area_drift": 0.5}
    floor = {"spatiotemporal_iou_tol": 0.0}
    still, parts = scene_headline(head, metrics, {"spatiotemporal_iou_tol": 0.0,
                                                  "body_area_drift": 0.0}, floor, {})
    assert still == 0.0 and parts["penalties"]["body_area_drift"]["subtracted"] == 0.0
    value, parts = scene_headline(head, metrics, {"spatiotemporal_iou_tol": 0.6,
                                                  "body_area_drift": 0.2}, floor, {})
    assert value == pytest.approx(0.6 - 0.5 * 0.2)
    # clipped after the penalty
    low, _ = scene_headline(head, metrics, {"spatiotemporal_iou_tol": 0.0,
                                            "body_area_drift": 1.386}, floor, {})
    assert low == pytest.approx(-0.693, abs=1e-3)
    assert scene_headline(head, metrics, {"spatiotemporal_iou_tol": 0.0,
                                          "body_area_drift": 5.0}, floor, {})[0] == -1.0
    # no value: nothing subtracted, and said why; no penalty configured: the plain mean
    value, parts = scene_headline(head, metrics, {"spatiotemporal_iou_tol": 0.6,
                                                  "body_area_drift": float("nan")}, floor, {})
    assert value == pytest.approx(0.6) and "undefined" in parts["penalties"]["body_area_drift"]
    # a penalty the run does not score subtracts nothing and says so
    value, parts = scene_headline(head, metrics[:1], {"spatiotemporal_iou_tol": 0.6}, floor, {})
    assert value == pytest.approx(0.6)
    assert "not among the run's metrics" in parts["penalties"]["body_area_drift"]["undefined"]
    plain = Headline.from_cfg({"headline": {"penalties": {}}})
    assert plain.penalties == ()
    assert scene_headline(plain, metrics, {"spatiotemporal_iou_tol": 0.6,
                                           "body_area_drift": 0.2}, floor, {})[0] == 0.6
    with pytest.raises(ValueError, match="penalties"):
        Headline.from_cfg({"headline": {"penalties": {"body_area_drift": -1}}})


@pytest.mark.parametrize("index", range(len(SCENES)))
def test_the_flow_extrapolation_loses_headline_to_its_drift(scenes, index):
    m = scenes[index]
    reg = get_registry()
    metrics = [reg.get("metrics", "spatiotemporal_iou_tol"), reg.get("metrics", "body_area_drift")]

    def headline(clip: str, penalties: dict) -> float:
        ref, gen = m["ref"], m["clips"][clip]
        inp = MetricInput(scene=m["scene"], reference=ref, generated=gen)
        a = unaligned(len(ref), len(gen))
        values = {x.name: x.compute_sequence(inp, a) for x in metrics}
        h = Headline.from_cfg({"headline": {"penalties": penalties}})
        return scene_headline(h, metrics, values, {"spatiotemporal_iou_tol": 0.0}, {})[0]

    with_penalty, without = headline("flow", {"body_area_drift": 0.5}), headline("flow", {})
    assert with_penalty == pytest.approx(without - 0.5 * m["drift"]["flow"])
    assert headline("still", {"body_area_drift": 0.5}) == 0.0
