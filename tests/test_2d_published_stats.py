"""The generated 2D subset has the published VisPhyBench clips' statistics.

Measured on the published clips and the paper: red-ball radius 17-39-56 px (min-median-max),
non-white area per frame 3.3-4.4-6.6 %, 1,523 objects over 209 scenes (about 7.3 per scene) in
six categories. Sizes, counts and categories are checked on every 2D slot's first candidate
(the builder's seed; nearly every slot keeps it); the rendered area on a sample of accepted,
simulated scenes (`benchmarks/bench_2d_stats.py` measures the whole catalogue).
"""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from visphy_core.spec.spec2d import CATEGORIES
from visphy_plugins.datasets.visphybench import blocks2d as bk
from visphy_plugins.datasets.visphybench.catalogue import MAX_ATTEMPTS, scene_seed
from visphy_plugins.datasets.visphybench.filters import (
    shared_pixels,
    validity_problems,
    window_mask,
)
from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d
from visphy_plugins.datasets.visphybench.templates_2d import (
    TEMPLATES_2D,
    decorate,
    flight_path,
)
from visphy_plugins.physics.box2d import simulate_2d

SLOTS = [(t, v) for t in TEMPLATES_2D for v in range(t.n_variants)]
AREA_SAMPLE = SLOTS[::4]


def _candidate(template, variant: int, attempt: int = 0) -> dict:
    seed = scene_seed(0, template.template_id, variant, attempt)
    return template.make(np.random.default_rng(seed), variant)


@pytest.fixture(scope="module")
def first_candidates() -> list[dict]:
    return [_candidate(t, v) for t, v in SLOTS]


def _red(spec: dict) -> dict:
    return next(b for b in spec["bodies"] if b["id"] == "red_ball")


def test_red_ball_radius_matches_the_published_clips(first_candidates):
    radii = np.array([_red(s)["shape"]["radius_px"] for s in first_candidates])
    assert len(radii) == 179
    assert radii.min() >= 17.0 and radii.max() <= 56.0
    assert 30.0 <= float(np.median(radii)) <= 48.0


def test_objects_per_scene_and_category_mix(first_candidates):
    n_objects = [len(s["bodies"]) for s in first_candidates]
    assert 6.0 <= np.mean(n_objects) <= 9.0, np.mean(n_objects)
    counts: Counter[str] = Counter(b["category"] for s in first_candidates for b in s["bodies"])
    assert set(counts) == set(CATEGORIES) and all(counts[c] > 0 for c in CATEGORIES)
    per_scene = {c: counts[c] / len(first_candidates) for c in CATEGORIES}
    # paper, 2D share of it (3D scenes carry the rest): ~4.1 circles, ~1.6 lines, ~1.5 rectangles
    assert 3.4 <= per_scene["circle"] <= 4.8, per_scene
    assert 1.2 <= per_scene["line"] <= 2.1, per_scene
    assert 1.1 <= per_scene["rectangle"] <= 1.9, per_scene
    assert 0.15 <= per_scene["u_shape"] <= 0.4, per_scene


def test_scenery_keeps_clear_of_the_red_balls_flight():
    """Scenery never sits in the red ball's obstacle-free flight, so the ball reaches its story."""
    rng = np.random.default_rng(3)
    for k in range(12):
        layout = bk.Layout()
        red = bk.ball("red_ball", "red", 40.0, 150.0 + 20 * k, 420.0,
                      velocity=(10.0 * k, 0.0, 0.0))
        story = layout.add([red, bk.bar("black_bar", "black", 200.0, 256.0, 60.0)])
        extras = decorate(rng, layout, list(story))[2:]
        assert len(extras) >= 1
        discs = [window_mask(red, (x, y, 0.0), 512, 512) for x, y in flight_path(red)]
        for b in extras:
            win = window_mask(b, (b["pose"]["x_px"], b["pose"]["y_px"], b["pose"]["angle_rad"]),
                              512, 512)
            assert all(shared_pixels(win, d) == 0 for d in discs), b["id"]


@pytest.fixture(scope="module")
def nonwhite_medians() -> list[float]:
    """Per accepted sampled scene, the median over its frames of the non-white pixel share (%)."""
    out = []
    for t, v in AREA_SAMPLE:
        for attempt in range(MAX_ATTEMPTS):
            spec = _candidate(t, v, attempt)
            rollout = simulate_2d(spec)
            if not validity_problems(spec, rollout):
                break
        frames = render_clip_2d(spec, rollout.frame_poses[::2])
        white = np.array(spec["render"]["background_rgb"], dtype=frames.dtype)
        shares = [100.0 * float(np.any(f != white, axis=-1).mean()) for f in frames]
        out.append(float(np.median(shares)))
    return out


def test_non_white_area_matches_the_published_clips(nonwhite_medians):
    med = np.array(nonwhite_medians)
    assert 3.3 <= float(np.median(med)) <= 6.6, float(np.median(med))
    # per scene: the published range, with a little slack for the sample's extremes
    assert med.min() >= 2.5 and med.max() <= 8.0, (med.min(), med.max())
