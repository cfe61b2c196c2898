"""Rasteriser (`visphy_plugins.datasets.visphybench.raster2d`): the pixel-centre fill rule,
orientation, palette
only (no anti-aliasing), draw order and a whole clip (its speed: benchmarks/bench_2d_stats.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mini_templates import ball, box, mini_scenes, scene

from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d, render_frame_2d
from visphy_plugins.physics.box2d import simulate_2d


def _one(body: dict) -> dict:
    return scene(98, 0, "", [body])


def _mask(spec: dict, colour) -> np.ndarray:
    frame = render_frame_2d(spec, [[b["pose"]["x_px"], b["pose"]["y_px"], b["pose"]["angle_rad"]]
                                   for b in spec["bodies"]])
    return np.all(frame == np.asarray(colour, dtype=np.uint8), axis=-1)


@pytest.mark.parametrize("r", [5.0, 17.3, 40.0])
def test_circle_covers_pi_r_squared(r):
    mask = _mask(_one(ball("red_ball", "red", r, 200.3, 300.7)), (243, 79, 70))
    assert abs(mask.sum() - math.pi * r * r) <= 2 * math.pi * r * 0.25 + 2
    ys, xs = np.nonzero(mask)
    assert xs.mean() + 0.5 == pytest.approx(200.3, abs=0.3)
    assert ys.mean() + 0.5 == pytest.approx(512 - 300.7, abs=0.3)


def test_box_fill_rule_is_pixel_centres():
    # edges at x = 100..140 and y = 20..30 (world): exactly 40 x 10 pixel centres inside
    mask = _mask(_one(box("purple_box", "purple", 40, 10, 120, 25)), (75, 74, 164))
    assert mask.sum() == 400
    rows, cols = np.nonzero(mask)
    assert (cols.min(), cols.max()) == (100, 139)
    assert (rows.min(), rows.max()) == (512 - 30, 512 - 21)  # y up: world y 20..30 near bottom


def test_rotation_is_ccw_with_y_up():
    bar = box("black_bar", "black", 200, 10.24, 256, 256, angle=math.radians(30))
    rows, cols = np.nonzero(_mask(_one(bar), (0, 0, 0)))
    right = cols > 300
    # CCW in world (y up): the right end is higher, i.e. has smaller image rows
    expected_row = 256 - (cols[right].mean() + 0.5 - 256) * math.tan(math.radians(30))
    assert rows[right].mean() + 0.5 == pytest.approx(expected_row, abs=1.0)
    assert len(rows) == pytest.approx(200 * 10.24, rel=0.03)


def test_draw_order_later_bodies_on_top_and_palette_only():
    spec = scene(98, 0, "", [box("purple_box", "purple", 100, 100, 256, 256),
                             ball("red_ball", "red", 20, 256, 256)])
    frame = render_frame_2d(spec, [[256, 256, 0], [256, 256, 0]])
    assert tuple(frame[256, 256]) == (243, 79, 70)
    colours = {tuple(c) for c in frame.reshape(-1, 3)}
    assert colours == {(255, 255, 255), (75, 74, 164), (243, 79, 70)}  # no blended edge pixels


def test_seventeen_frames_render():
    # its speed (< 1 s per clip) is benchmarks/bench_2d_stats.py's `render_s_per_clip`
    spec, rollout = mini_scenes()[1]
    clip = render_clip_2d(spec, rollout.frame_poses)
    assert clip.shape == (17, 512, 512, 3) and clip.dtype == np.uint8
    assert not np.array_equal(clip[0], clip[-1])


def test_pose_shape_is_checked():
    spec = _one(ball("red_ball", "red", 5, 50, 50))
    with pytest.raises(ValueError, match="poses shape"):
        render_frame_2d(spec, np.zeros((2, 3)))
    assert simulate_2d(spec).frame_poses.shape[1] == 1
