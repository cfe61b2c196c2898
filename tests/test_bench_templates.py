"""Hand-made mini scenes (`mini_templates (tests/mini_templates.py)`): PHYRE conventions, a clean
initial
layout, visible motion, honest annotations and deterministic output."""

from __future__ import annotations

import itertools
import json
import re

import numpy as np
import pytest
from mini_templates import mini_scenes

from visphy_core.spec.spec2d import shape_area_centroid
from visphy_plugins.datasets.visphybench.raster2d import PALETTE, body_mask


@pytest.fixture(scope="module")
def scenes():
    return mini_scenes()


def test_phyre_conventions(scenes):
    assert len(scenes) >= 3
    ids = [spec["scene_id"] for spec, _ in scenes]
    assert len(set(ids)) == len(ids)
    palette = {tuple(v) for k, v in PALETTE.items() if k != "white"}
    categories = set()
    for spec, _ in scenes:
        assert re.fullmatch(r"task\d{5}_\d{3}", spec["scene_id"])
        assert spec["scene_id"] == f"task{spec['template_id']}_{spec['variant']:03d}"
        w = spec["world"]
        assert (w["n_frames"], w["video_fps"], w["steps_per_frame"]) == (17, 5, 60)
        reds = [b for b in spec["bodies"] if b["color_rgb"] == [243, 79, 70]]
        assert len(reds) == 1 and reds[0]["dynamic"] and reds[0]["category"] == "circle"
        for b in spec["bodies"]:
            assert tuple(b["color_rgb"]) in palette
            assert b["dynamic"] == (tuple(b["color_rgb"]) not in {(0, 0, 0), (75, 74, 164)})
            if b["category"] == "line":
                assert b["shape"]["thickness_px"] == pytest.approx(512 / 50)
            categories.add(b["category"])
    assert {"circle", "line", "rectangle", "u_shape"} <= categories


def test_everything_on_screen_and_nothing_overlaps_at_t0(scenes):
    for spec, _ in scenes:
        masks = [body_mask(spec, i) for i in range(len(spec["bodies"]))]
        for body, mask in zip(spec["bodies"], masks):
            area = shape_area_centroid(body["shape"])[0]
            assert mask.sum() == pytest.approx(area, rel=0.05), (spec["scene_id"], body["id"])
        for (i, a), (j, b) in itertools.combinations(enumerate(masks), 2):
            assert not np.any(a & b), (spec["scene_id"], spec["bodies"][i]["id"],
                                       spec["bodies"][j]["id"])


def test_something_moves_clearly_and_events_are_recorded(scenes):
    for spec, rollout in scenes:
        travel = np.hypot(*(rollout.frame_poses[-1, :, :2] - rollout.frame_poses[0, :, :2]).T)
        assert travel.max() > 50, spec["scene_id"]
        assert any(e["a"] in ("red_ball",) or e["b"] == "red_ball"
                   for e in spec["ground_truth"]["events"]), spec["scene_id"]


def test_annotations_are_consistent_with_the_rollout(scenes):
    for spec, rollout in scenes:
        d = spec["difficulty"]
        assert d["features"]["n_dynamic"] == sum(b["dynamic"] for b in spec["bodies"])
        want = "easy" if d["score"] <= 4.5 else "medium" if d["score"] <= 8 else "hard"
        assert d["label"] == want
        ident = spec["ground_truth"]["identifiable"]
        # gravity is claimed identifiable only if some body really shows -58.8 px/frame^2
        y = rollout.frame_poses[:, :, 1]
        free = np.isclose(y[2:] - 2 * y[1:-1] + y[:-2], -58.8, atol=0.05)
        dynamic = np.array([b["dynamic"] for b in spec["bodies"]])
        assert ident["gravity"] == bool(free[:, dynamic].any()), spec["scene_id"]
        moving = [b["id"] for b in spec["bodies"]
                  if b["dynamic"] and any(b["velocity"].values())]
        assert ident["initial_velocity"] == moving
    assert any(spec["ground_truth"]["identifiable"]["gravity"] for spec, _ in scenes)
    assert len({spec["difficulty"]["label"] for spec, _ in scenes}) >= 2


def test_generation_is_deterministic(scenes):
    again = mini_scenes()
    for (s1, r1), (s2, r2) in zip(scenes, again):
        assert json.dumps(s1) == json.dumps(s2)
        assert np.array_equal(r1.step_poses, r2.step_poses)
