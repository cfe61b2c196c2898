"""The 2D template catalogue: counts, validity by sampling, category mix, laws, filter, features."""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest

from visphy_core.spec.spec2d import (
    PHYRE_PROFILE,
    WALL_IDS,
    category_of,
    shape_area_centroid,
    validate_spec,
)
from visphy_plugins.datasets.visphybench import blocks2d as bk
from visphy_plugins.datasets.visphybench import templates_2d as t2d
from visphy_plugins.datasets.visphybench.features import difficulty_features, difficulty_score
from visphy_plugins.datasets.visphybench.filters import REASONS, validity_problems
from visphy_plugins.datasets.visphybench.raster2d import PALETTE
from visphy_plugins.datasets.visphybench.templates_2d import (
    TARGET_SHARES,
    TEMPLATES_2D,
    category_shares,
)
from visphy_plugins.physics.box2d import simulate_2d

DRAWS = 4
DYNAMIC_RGB = {tuple(PALETTE[c]) for c in ("gray", "green", "blue")}
STATIC_RGB = {tuple(PALETTE[c]) for c in ("black", "purple")}


def _draw(template, k: int) -> dict:
    return template.make(np.random.default_rng(template.template_id * 100 + k),
                         k % template.n_variants)


@pytest.fixture(scope="module")
def draws():
    """For every template, the first DRAWS candidates: (variant, spec, problems)."""
    out = {}
    for t in TEMPLATES_2D:
        rows = []
        for k in range(DRAWS):
            spec = _draw(t, k)
            rollout = simulate_2d(spec)
            rows.append((k % t.n_variants, spec, validity_problems(spec, rollout)))
        out[t.template_id] = rows
    return out


def test_catalogue_counts_and_ids():
    ids = [t.template_id for t in TEMPLATES_2D]
    assert len(TEMPLATES_2D) == 96 and len(set(ids)) == 96
    assert sorted(ids) == list(range(10001, 10097))
    assert sum(t.n_variants for t in TEMPLATES_2D) == 179
    families = {t.family for t in TEMPLATES_2D}
    assert families == {"combinatorial", "law"}
    n_law = sum(t.family == "law" for t in TEMPLATES_2D)
    assert 20 <= n_law <= 32 and {t.law for t in TEMPLATES_2D if t.family == "law"} == {
        "gravity", "restitution", "friction", "initial_velocity", "mass_ratio"}


def test_every_draw_is_a_valid_phyre_style_spec(draws):
    for t in TEMPLATES_2D:
        for variant, spec, _ in draws[t.template_id]:
            validate_spec(spec)
            assert spec["scene_id"] == f"task{t.template_id:05d}_{variant:03d}"
            assert re.fullmatch(r"task\d{5}_\d{3}", spec["scene_id"]) and spec["seed"] == 0
            world = spec["world"]
            assert world["units"]["canvas_px"] == [512, 512]
            assert world["n_frames"] == 17 and world["video_fps"] == 5
            assert world["dt_s"] == PHYRE_PROFILE["dt_s"] and world["steps_per_frame"] == 60
            red = [b for b in spec["bodies"] if b["id"] == "red_ball"]
            assert len(red) == 1 and red[0]["dynamic"]
            assert red[0]["color_rgb"] == list(PALETTE["red"]) and category_of(red[0]) == "circle"
            for b in spec["bodies"]:
                if b is red[0]:
                    continue
                allowed = DYNAMIC_RGB if b["dynamic"] else STATIC_RGB
                assert tuple(b["color_rgb"]) in allowed, (spec["scene_id"], b["id"])


def test_each_template_is_valid_with_probability_at_least_half(draws):
    rates = {"combinatorial": [], "law": []}
    for t in TEMPLATES_2D:
        ok = [not problems for _, _, problems in draws[t.template_id]]
        assert any(ok), (t.template_id, [p for _, _, p in draws[t.template_id]])
        assert sum(ok) >= DRAWS // 2, (t.template_id, [p for _, _, p in draws[t.template_id]])
        rates[t.family].extend(ok)
        for _, _, problems in draws[t.template_id]:
            assert set(problems) <= set(REASONS) and len(problems) == len(set(problems))
    for family, ok in rates.items():
        assert np.mean(ok) >= 0.75, family


def test_category_shares_match_visphybench(draws):
    specs = []
    for t in TEMPLATES_2D:
        for v in range(t.n_variants):
            valid = [s for var, s, p in draws[t.template_id] if var == v and not p]
            k = DRAWS + v
            while not valid:  # draw further candidates of this variant, as the builder would
                spec = t.make(np.random.default_rng(t.template_id * 100 + k), v)
                if not validity_problems(spec, simulate_2d(spec)):
                    valid = [spec]
                k += t.n_variants
            specs.append(valid[0])
    assert len(specs) == 179
    shares = category_shares(specs)
    for cat, target in TARGET_SHARES.items():
        assert abs(shares[cat] - target) <= 0.04, (cat, shares[cat], target)


def test_categories_of_a_template_do_not_depend_on_the_draw(draws):
    for t in TEMPLATES_2D:
        cats = {frozenset(category_of(b) for b in spec["bodies"])
                for _, spec, _ in draws[t.template_id]}
        assert len(cats) == 1, (t.template_id, cats)


def _law_specs(law: str) -> list[tuple[int, dict]]:
    return [(v, t.make(np.random.default_rng(t.template_id * 7 + v), v))
            for t in TEMPLATES_2D if t.law == law for v in range(t.n_variants)]


def test_gravity_templates_vary_gravity_only():
    specs = _law_specs("gravity")
    gs = [-s["world"]["gravity_m_s2"][1] for _, s in specs]
    assert all(4.0 <= g <= 16.0 for g in gs) and len(set(gs)) == len(gs)
    for (v, s), g in zip(specs, gs):
        assert s["world"]["gravity_m_s2"][0] == 0.0 and (g < 10.0) == (v == 0)
        assert s["world"]["profile"] == bk.GRAVITY_PROFILE
        assert s["contacts"]["pairs"] == []


def test_restitution_and_friction_templates_use_explicit_pairs():
    for law, key, other in (("restitution", "restitution", "friction"),
                            ("friction", "friction", "restitution")):
        for v, s in _law_specs(law):
            pairs = s["contacts"]["pairs"]
            assert pairs, s["scene_id"]
            ids = {b["id"] for b in s["bodies"]} | set(WALL_IDS)
            for p in pairs:
                assert p["a"] in ids and p["b"] in ids
                assert 0.1 <= p[key] <= 0.9 and (p[key] < 0.5) == (v == 0)
                assert p[other] == PHYRE_PROFILE[other]
            assert s["world"]["profile"] == "phyre"


def test_velocity_and_mass_templates_vary_their_law():
    speeds = []
    for v, s in _law_specs("initial_velocity"):
        red = next(b for b in s["bodies"] if b["id"] == "red_ball")
        speed = float(np.hypot(red["velocity"]["vx_px_s"], red["velocity"]["vy_px_s"]))
        assert 50.0 <= speed <= 250.0 and (speed < 150.0) == (v == 0)
        speeds.append(speed)
    assert len(set(np.round(speeds, 3))) == len(speeds)
    for v, s in _law_specs("mass_ratio"):
        dens = {b["id"]: b["material"]["density_kg_m2"] for b in s["bodies"]
                if b["dynamic"] and b["category"] != "line"}  # a seesaw's plank keeps 0.25
        assert all(0.1 <= d <= 2.0 for d in dens.values())
        red = dens.pop("red_ball")
        assert dens and all((red > d) == (v == 0) for d in dens.values())


def test_building_blocks_have_the_paper_categories_and_exact_geometry():
    blocks = [bk.ball("red_ball", "red", 15, 60, 400), bk.bar("black_bar", "black", 200, 256, 300),
              bk.box("gray_box", "gray", 40, 30, 100, 100),
              bk.jar("gray_jar", "gray", 90, 60, 300, 100),
              bk.sticks("green_sticks", "green", 100, 0.8, 420, 200),
              bk.triangle("blue_triangle", "blue", 60, 40, 200, 150, apex=0.0),
              bk.regular_polygon("gray_hexagon", "gray", 6, 20, 420, 420)]
    assert [category_of(b) for b in blocks] == ["circle", "line", "rectangle", "u_shape",
                                                "composite_shape", "triangle",
                                                "composite_shape"]
    area, cx, cy = shape_area_centroid(blocks[4]["shape"])  # five disjoint parts of an X
    assert area == pytest.approx(2 * 100 * bk.BAR - bk.BAR ** 2 / np.sin(0.8))
    assert abs(cx) < 1e-9 and abs(cy) < 1e-9
    spec = _base_scene(blocks)
    validate_spec(spec)
    bk.mirror(spec["bodies"])
    validate_spec(spec)  # polygons stay counter-clockwise
    assert spec["bodies"][0]["pose"]["x_px"] == 512 - 60
    low = bk.rest_on_floor(bk.sticks("gray_sticks", "gray", 90, 1.0, 100, 300))
    assert bk.extent(low)[2] == pytest.approx(bk.GAP)


def _base_scene(bodies: list[dict]) -> dict:
    return bk.scene2d(10001, 0, "combinatorial", "constructed", bodies)


def test_filter_accepts_a_clean_scene_and_catches_constructed_bad_cases():
    ok = _base_scene([bk.ball("red_ball", "red", 15, 200, 400),
                      bk.bar("black_bar", "black", 200, 256, 150, 0.3)])
    assert validity_problems(ok, simulate_2d(ok)) == []

    def problems(spec):
        validate_spec(spec)
        return validity_problems(spec, simulate_2d(spec))

    overlap = _base_scene([bk.ball("red_ball", "red", 15, 200, 400),
                           bk.ball("gray_ball", "gray", 15, 210, 405)])
    assert "overlap" in problems(overlap)
    off = _base_scene([bk.ball("red_ball", "red", 15, -50, 400)])
    assert "offscreen" in problems(off)
    still = _base_scene([bk.ball("red_ball", "red", 15, 200, 400, dynamic=False),
                         bk.bar("black_bar", "black", 200, 256, 150, 0.3)])
    assert problems(still) == ["static"]
    resting = _base_scene([bk.ball("red_ball", "red", 15, 200, 15.5)])
    assert problems(resting) == ["static"]
    fast = _base_scene([bk.ball("red_ball", "red", 15, 256, 256,
                                velocity=(4000.0 * 6.0, 0.0, 0.0))])
    assert "speed_cap" in problems(fast)
    embedded = _base_scene([bk.ball("red_ball", "red", 15, 100, 400),
                            bk.bar("black_bar", "black", 300, 256, 100),
                            bk.box("gray_box", "gray", 40, 40, 256, 100)])
    assert {"overlap", "tunnelling"} <= set(problems(embedded))
    leak = copy.deepcopy(ok)
    leak["world"]["walls"]["sides"] = []  # nothing stops the fall: the ball leaves the canvas
    leak["bodies"] = leak["bodies"][:1]
    assert "tunnelling" in problems(leak)


def test_features_are_deterministic_and_the_score_is_monotone():
    t = TEMPLATES_2D[0]
    spec = _draw(t, 0)
    rollout = simulate_2d(spec)
    f1 = difficulty_features(spec, rollout)
    f2 = difficulty_features(copy.deepcopy(spec), simulate_2d(spec))
    assert f1 == f2
    assert set(f1) >= {"n_dynamic", "n_contacts", "rotation_over_30deg", "max_rotation_deg",
                       "sensitivity_px", "chaotic", "occlusion", "n_bodies"}
    assert f1["occlusion"] == 0.0 and f1["chaotic"] == (f1["sensitivity_px"] > 16)
    assert f1["n_bodies"] == len(spec["bodies"])
    base = difficulty_score(f1)
    for key, bump in (("n_dynamic", 1), ("n_contacts", 1), ("rotation_over_30deg", True),
                      ("max_rotation_deg", 45.0), ("sensitivity_px", 20.0), ("chaotic", True),
                      ("occlusion", 0.5), ("n_bodies", 1)):
        more = dict(f1)
        more[key] = (more[key] + bump) if not isinstance(bump, bool) else True
        assert difficulty_score(more) >= base, key


def test_make_is_deterministic_and_survives_an_impossible_layout(monkeypatch):
    t = t2d.template_by_id(10030)
    a = t.make(np.random.default_rng(5), 1)
    b = t.make(np.random.default_rng(5), 1)
    assert a == b
    monkeypatch.setattr(bk.Layout, "_free", lambda self, body: False)
    spec = t.make(np.random.default_rng(5), 0)  # the last attempt keeps its draw
    validate_spec(spec)
