"""Detection context (`visphy_plugins.datasets.visphybench.detection`) against the rendered first
frame, and its
conventions (top-left origin, y down, clockwise-positive angles)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mini_templates import box, jar, mini_scenes, scene

from visphy_plugins.datasets.visphybench.detection import detection_from_spec
from visphy_plugins.datasets.visphybench.raster2d import render_frame_2d


@pytest.fixture(scope="module")
def scenes():
    return mini_scenes()


def test_schema_of_the_detection(scenes):
    spec, rollout = scenes[0]
    det = detection_from_spec(spec, rollout.frame_poses[0])
    assert det["image_size"] == {"width": 512, "height": 512}
    assert det["coordinate_system"] == {"origin": "top_left", "x_axis": "to_right",
                                        "y_axis": "down", "units": "pixels"}
    assert [o["id"] for o in det["objects"]] == [b["id"] for b in spec["bodies"]]
    for obj in det["objects"]:
        assert set(obj) >= {"id", "category", "color_rgb", "bbox", "position", "size"}
        assert ("orientation" in obj) == (obj["category"] != "circle")
        if obj["category"] == "circle":
            assert set(obj["size"]) == {"radius_pixels"}
        if obj["category"] == "line":
            assert obj["size"]["thickness_pixels"] == pytest.approx(10.24)


def test_centres_and_boxes_agree_with_the_rendered_first_frame(scenes):
    checked = 0
    for spec, rollout in scenes:
        frame = render_frame_2d(spec, rollout.frame_poses[0])
        det = detection_from_spec(spec, rollout.frame_poses[0])
        colours = [tuple(b["color_rgb"]) for b in spec["bodies"]]
        for obj in det["objects"]:
            if colours.count(tuple(obj["color_rgb"])) != 1:
                continue  # a shared colour cannot be attributed to one object
            ys, xs = np.nonzero(np.all(frame == np.asarray(obj["color_rgb"], np.uint8), axis=-1))
            where = (spec["scene_id"], obj["id"])
            assert abs(xs.mean() + 0.5 - obj["position"]["center_x"]) <= 2, where
            assert abs(ys.mean() + 0.5 - obj["position"]["center_y"]) <= 2, where
            bb = obj["bbox"]
            assert bb["x_min"] - 0.01 <= xs.min() + 0.5 and xs.max() + 0.5 <= bb["x_max"] + 0.01
            assert bb["y_min"] - 0.01 <= ys.min() + 0.5 and ys.max() + 0.5 <= bb["y_max"] + 0.01
            # tight: a rotated corner may fall between pixel centres, never by 2 px
            assert xs.min() + 0.5 - bb["x_min"] <= 2 and bb["y_max"] - ys.max() - 0.5 <= 2
            checked += 1
    assert checked >= 8


def test_jar_centre_is_its_area_centroid_above_the_base():
    spec = scene(97, 0, "", [jar("gray_jar", "gray", 100, 70, 256, 5.62)])
    det = detection_from_spec(spec)
    obj = det["objects"][0]
    assert obj["category"] == "u_shape"
    assert obj["position"]["center_x"] == pytest.approx(256)
    assert 512 - 70 < obj["position"]["center_y"] < 512 - 5.62  # above the base, y down
    assert obj["bbox"]["height"] == pytest.approx(70 + 10.24 / 2, abs=0.01)


def test_angles_are_clockwise_positive_in_image_convention():
    bar = box("black_bar", "black", 180, 10.24, 200, 150, angle=-0.35)  # slopes down to the right
    obj = detection_from_spec(scene(97, 0, "", [bar]))["objects"][0]
    assert obj["category"] == "line"
    assert obj["orientation"]["angle_deg"] == pytest.approx(20.05, abs=0.01)
    assert obj["position"] == {"center_x": 200.0, "center_y": 362.0}
    half_w = 90 * math.cos(0.35) + 5.12 * math.sin(0.35)
    assert obj["bbox"]["width"] == pytest.approx(2 * half_w, abs=0.01)
    flipped = box("black_bar", "black", 180, 10.24, 200, 150, angle=-0.35 + math.pi)
    obj2 = detection_from_spec(scene(97, 0, "", [flipped]))["objects"][0]
    assert obj2["orientation"]["angle_deg"] == pytest.approx(20.05, abs=0.01)  # bars: mod 180
