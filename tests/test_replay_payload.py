"""The one replay payload every reference program and the 3D ground-truth renderer read."""

from __future__ import annotations

import json

import numpy as np
import pytest

from visphy_core.spec.replay import fill, payload_from, replay_payload
from visphy_plugins.engines.threejs import replay_html_3d


def _spec_2d() -> dict:
    return {"scene_id": "s2", "dim": "2d", "render": {"background_rgb": [250, 240, 230]},
            "bodies": [
                {"id": "ball", "color_rgb": [243, 79, 70],
                 "shape": {"type": "circle", "radius_px": 12.5}},
                {"id": "bar", "color_rgb": [0, 0, 0],
                 "shape": {"type": "box", "length_px": 100.0, "thickness_px": 10.0}},
                {"id": "jar", "color_rgb": [1, 2, 3],
                 "shape": {"type": "compound", "parts_px": [[[0, 0], [4, 0], [4, 4]],
                                                            [[0, 0], [-4, 0], [-4, -4]]]}}]}


def test_2d_payload_is_in_spec_order_with_drawable_geometry():
    spec = _spec_2d()
    # the trajectory lists bodies in another order than the spec
    ids = ["jar", "ball", "bar"]
    poses = np.zeros((3, 3, 3))
    for k in range(3):
        for i, bid in enumerate(ids):
            poses[k, i] = [k * 10 + i, -0.0, 0.1 * i]
    p = payload_from(spec, ids, poses, fps=5, n_frames=2, width=64, height=48)
    assert (p["dim"], p["width"], p["height"], p["fps"], p["n_frames"]) == ("2d", 64, 48, 5.0, 2)
    assert p["background_rgb"] == [250, 240, 230]
    assert [b["id"] for b in p["bodies"]] == ["ball", "bar", "jar"]
    assert p["bodies"][0]["radius"] == 12.5 and "polygons" not in p["bodies"][0]
    assert p["bodies"][1]["polygons"] == [[[-50, -5], [50, -5], [50, 5], [-50, 5]]]
    assert len(p["bodies"][2]["polygons"]) == 2
    assert p["bodies"][1]["shape"] == spec["bodies"][1]["shape"]  # the spec's own shape too
    assert len(p["frame_poses"]) == 2                   # cut to n_frames
    assert p["frame_poses"][1] == [[11, 0.0, 0.1], [12, 0.0, 0.2], [10, 0.0, 0.0]]
    assert "-0.0" not in json.dumps(p)


def test_payload_errors_name_what_is_missing():
    spec = _spec_2d()
    with pytest.raises(ValueError, match="no poses for bodies"):
        payload_from(spec, ["ball"], np.zeros((1, 1, 3)), fps=5, n_frames=1, width=8, height=8)
    with pytest.raises(ValueError, match="frame_poses shape"):
        payload_from(spec, ["ball", "bar", "jar"], np.zeros((1, 3, 7)), fps=5, n_frames=1,
                     width=8, height=8)


def test_every_engine_reads_the_same_payload(mini_scenes):
    """The reference programs of all five engines embed the scene's one payload."""
    from visphy_core.api.registry import get_registry

    scene = mini_scenes[0]
    payload = replay_payload(scene)
    text = json.dumps(payload, separators=(",", ":"))
    for name in ("threejs", "p5", "svg", "manim", "blender"):
        engine = get_registry().get("engines", name)()
        try:
            source = engine.program_from_spec(scene).source
        finally:
            engine.close()
        assert text in source or repr(text) in source, name


def test_3d_page_embeds_the_payload_of_the_spec_order():
    spec = {"scene_id": "s3", "dim": "3d",
            "camera": {"fov_deg": 45.0, "position": [7, 6.2, 8.2], "look_at": [0, 1.2, 0],
                       "width": 32, "height": 24},
            "render": {"background_rgb": [255, 255, 255], "shadows": False,
                       "lighting": {"hemisphere": {"intensity": 1}, "directional": {}}},
            "world": {"floor": {"y": 0.0, "color_rgb": [151, 151, 151]}},
            "bodies": [{"id": "a", "color_rgb": [1, 2, 3],
                        "shape": {"type": "sphere", "radius_m": 0.1}}]}
    poses = np.array([[[1.23456789, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]]])
    html = replay_html_3d(spec, poses, 15, 1)
    payload = json.loads(html.split("const SCENE = ")[1].split(";\n")[0])
    assert payload["frame_poses"] == [[[1.234568, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]]]
    assert (payload["width"], payload["height"]) == (32, 24)  # the camera's size
    assert payload["camera"]["position"] == [7, 6.2, 8.2]
    assert payload["floor"]["color_rgb"] == [151, 151, 151]
    assert fill("x=__SCENE_JSON__;", {"a": 1}) == 'x={"a":1};'
