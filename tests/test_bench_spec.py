"""Scene-spec schema (`visphy_core.spec.spec2d`): accepts the mini scenes, rejects bad specs with a
one-line message naming the scene and the JSON path of the problem, and the category rule."""

from __future__ import annotations

import copy

import pytest
from mini_templates import mini_specs

from visphy_core.spec.spec2d import category_of, validate_spec


@pytest.fixture(scope="module")
def specs() -> list[dict]:
    return mini_specs()


def test_mini_specs_are_valid(specs):
    assert len(specs) >= 3
    for spec in specs:
        validate_spec(spec)


def _error(spec: dict) -> str:
    with pytest.raises(ValueError) as info:
        validate_spec(spec)
    message = str(info.value)
    assert "\n" not in message and spec["scene_id"] in message
    return message


@pytest.mark.parametrize("mutate, path", [
    (lambda s: s["bodies"][0]["shape"].update(radius_px=-3), "$.bodies[0].shape.radius_px"),
    (lambda s: s["world"].pop("dt_s"), "$.world.dt_s"),
    (lambda s: s["bodies"][1].update(colour=[1, 2, 3]), "$.bodies[1].colour"),
    (lambda s: s["bodies"][0]["color_rgb"].__setitem__(0, 300), "$.bodies[0].color_rgb[0]"),
    (lambda s: s["bodies"][0].pop("velocity"), "$.bodies[0].velocity"),
    (lambda s: s["world"]["units"].update(px_per_m=10.0), "$.world.units.px_per_m"),
    (lambda s: s["world"].update(dt_s=0.01), "$.world.dt_s"),
    (lambda s: s["contacts"]["pairs"].append({"a": "red_ball", "b": "ghost", "friction": 0.5,
                                              "restitution": 0.2}), "$.contacts.pairs[0].b"),
    (lambda s: s["bodies"][1].update(id="red_ball"), "$.bodies[1].id"),
    (lambda s: s["bodies"][1].update(category="circle"), "$.bodies[1].category"),
    (lambda s: s.update(scene_id="scene_1"), "$.scene_id"),
])
def test_bad_specs_are_rejected_naming_the_field(specs, mutate, path):
    bad = copy.deepcopy(specs[0])  # task00001_000: red ball, black bar, purple box, gray ball
    mutate(bad)
    message = _error(bad)
    assert f"{path}:" in message, message


def test_non_convex_and_clockwise_polygons_are_rejected(specs):
    spec = copy.deepcopy(specs[0])
    body = spec["bodies"][2]
    body["shape"] = {"type": "polygon", "vertices_px": [[0, 0], [40, 0], [10, 10], [40, 40],
                                                         [0, 40]]}
    body["category"] = "composite_shape"
    assert "$.bodies[2].shape.vertices_px: polygon must be strictly convex" in _error(spec)
    body["shape"]["vertices_px"] = [[0, 0], [0, 40], [40, 0]]  # clockwise triangle
    body["category"] = "triangle"
    assert "counter-clockwise" in _error(spec)
    body["shape"]["vertices_px"] = [[0, 0], [40, 0], [0, 40]]
    validate_spec(spec)


def test_category_rule():
    def cat(shape: dict) -> str:
        return category_of({"shape": shape})

    assert cat({"type": "circle", "radius_px": 5}) == "circle"
    assert cat({"type": "box", "length_px": 100, "thickness_px": 10.24}) == "line"
    assert cat({"type": "box", "length_px": 40.96, "thickness_px": 10.24}) == "line"  # ratio 4
    assert cat({"type": "box", "length_px": 40, "thickness_px": 10.24}) == "rectangle"
    assert cat({"type": "box", "length_px": 10.24, "thickness_px": 100}) == "line"
    assert cat({"type": "polygon", "vertices_px": [[0, 0], [9, 0], [0, 9]]}) == "triangle"
    assert cat({"type": "polygon",
                "vertices_px": [[0, 0], [50, 0], [50, 5], [0, 5]]}) == "line"
    assert cat({"type": "compound", "parts_px": [[[0, 0], [1, 0], [0, 1]]] * 3}) == "u_shape"
    two_triangles = {"type": "compound", "parts_px": [[[0, 0], [1, 0], [0, 1]]] * 2}
    assert cat(two_triangles) == "composite_shape"
