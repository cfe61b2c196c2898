"""The Blender engine's 3D reference program draws the published look's new payload fields:
an anti-aliased render and a translucent body (``opacity``) that shows what is behind it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from visphy_core.api.engine import RenderContract
from visphy_plugins.engines.blender import BlenderEngine, find_blender_python

pytestmark = [pytest.mark.blender, pytest.mark.skipif(find_blender_python() is None,
                                                  reason="Blender venv missing")]


@pytest.fixture(scope="module")
def engine():
    return BlenderEngine()


def _scene(tmp_path, opacity: float | None, antialias: bool):
    from visphy_core.api.scene import Scene
    from visphy_core.infra.video import ClipInfo

    cam = {"type": "perspective", "fov_deg": 45.0, "near": 0.1, "far": 100.0,
           "position": [7.0, 6.2, 8.2], "look_at": [0.0, 1.2, 0.0], "up": [0.0, 1.0, 0.0],
           "width": 128, "height": 128}
    q0 = [0.0, 0.0, 0.0, 1.0]
    wall = {"id": "gray_container", "color_rgb": [75, 74, 164],
            "shape": {"type": "box", "size_m": [3.0, 2.0, 0.2]}}
    if opacity is not None:
        wall["opacity"] = opacity
    bodies = [{"id": "red_ball", "color_rgb": [243, 79, 70],
               "shape": {"type": "sphere", "radius_m": 0.6}}, wall]
    light = {"hemisphere": {"sky_rgb": [255, 255, 255], "ground_rgb": [110, 110, 110],
                            "intensity": 1.6},
             "directional": {"color_rgb": [255, 255, 255], "intensity": 2.0,
                             "position": [-3.0, 10.0, 6.0]}}
    spec = {"scene_id": "99_tmpl_00", "dim": "3d", "camera": cam, "bodies": bodies,
            "render": {"background_rgb": [255, 255, 255], "shadows": False,
                       "antialias": antialias, "lighting": light},
            "world": {"floor": {"y": 0.0, "color_rgb": [148, 148, 148], "size_m": 18.0}}}
    # the wall stands between the camera and the ball
    frames = [[[0.0, 0.6, 0.0] + q0, [1.4, 1.0, 1.6] + q0]] * 2
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    np.savez(tmp_path / "traj.npz", body_ids=np.array([b["id"] for b in bodies]),
             frame_poses=np.array(frames))
    return Scene(scene_id="99_tmpl_00", dim="3d",
                 clip=ClipInfo(fps=15.0, n_frames=2, width=128, height=128),
                 video_path=tmp_path / "unused.mp4", spec_path=tmp_path / "spec.json",
                 trajectory_path=tmp_path / "traj.npz")


def _render(engine, scene) -> np.ndarray:
    result = engine.render(engine.program_from_spec(scene), RenderContract.for_scene(scene))
    assert result.ok, (result.error, result.logs[-5:])
    return result.frames[0].astype(int)


def test_blender_reference_draws_translucent_bodies_and_antialiases(engine, tmp_path):
    solid = _render(engine, _scene(tmp_path / "a", None, False))
    glass = _render(engine, _scene(tmp_path / "b", 0.5, False))
    smooth = _render(engine, _scene(tmp_path / "c", None, True))
    redness = lambda f: (f[..., 0] > 1.8 * np.maximum(f[..., 1], f[..., 2])).sum()  # noqa: E731
    # the wall hides part of the ball; translucent, the ball shows through it (tinted)
    assert np.abs(glass - solid).max(axis=2).sum() > 0
    tinted = (glass[..., 0] > glass[..., 1] + 20) & (solid[..., 2] > solid[..., 0] + 40)
    assert tinted.sum() >= 20, tinted.sum()
    assert redness(glass) >= redness(solid)
    # anti-aliasing: more distinct colours (edge pixels between neighbours)
    n_colours = lambda f: len(np.unique(f.reshape(-1, 3), axis=0))  # noqa: E731
    assert n_colours(smooth) > n_colours(solid)
