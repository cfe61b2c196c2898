"""The 3D subset's ground truth: schema, cannon-es rollouts, templates, replay, detection."""

from __future__ import annotations

import copy
import shutil

import numpy as np
import pytest

from visphy_core.spec.spec3d import RED_RGB, validate_spec_3d
from visphy_plugins.datasets.visphybench.detection3d import detection_from_spec_3d, project_points
from visphy_plugins.datasets.visphybench.screening3d import (
    REASONS,
    difficulty_features_3d,
    validity_problems_3d,
)
from visphy_plugins.datasets.visphybench.templates_3d import TEMPLATES_3D
from visphy_plugins.physics.cannon import simulate_3d, trajectory_digest_3d

pytestmark = pytest.mark.skipif(shutil.which("node") is None,
                                reason="Node.js not installed (needed by the cannon-es rollouts)")


def _first_valid(template, variant: int = 0, draws: int = 4):
    """(spec, rollout, draw) of the first valid candidate, drawing rng(template_id*100 + k)."""
    for k in range(draws):
        spec = template.make(np.random.default_rng(template.template_id * 100 + k), variant)
        validate_spec_3d(spec)
        rollout = simulate_3d(spec)
        if not validity_problems_3d(spec, rollout):
            return spec, rollout, k
    return None


@pytest.fixture(scope="module")
def valid_scenes():
    return {t.template_id: _first_valid(t) for t in TEMPLATES_3D}


PUBLISHED_CAMERA = {"type": "perspective", "fov_deg": 45.0, "position": [7.0, 6.2, 8.2],
                    "look_at": [0.0, 1.2, 0.0], "up": [0.0, 1.0, 0.0], "width": 512,
                    "height": 512}


def test_every_scene_has_the_published_fixed_camera_floor_and_look():
    cams = []
    for t in TEMPLATES_3D:
        for v in range(t.n_variants):
            for k in range(2):
                spec = t.make(np.random.default_rng(t.template_id * 100 + v * 10 + k), v)
                cams.append(spec["camera"])
                assert {key: spec["camera"][key] for key in PUBLISHED_CAMERA} == PUBLISHED_CAMERA
                floor, render = spec["world"]["floor"], spec["render"]
                assert (floor["y"], floor["size_m"]) == (0.0, 18.0)
                assert render["antialias"] is True and render["shadows"] is False
                for b in spec["bodies"]:
                    assert b.get("opacity", 1.0) == (0.5 if "container" in b["id"] else 1.0)
                    assert tuple(b["color_rgb"]) != (0, 0, 0)  # coloured, never solid black
    assert all(c == cams[0] for c in cams)  # one camera, identical in every clip


def test_the_floor_is_seen_corner_on_its_far_edge_a_caret():
    spec = TEMPLATES_3D[0].make(np.random.default_rng(100), 0)
    far, left, right = project_points(spec, [[-9.0, 0.0, -9.0], [-9.0, 0.0, 9.0],
                                             [9.0, 0.0, -9.0]])
    assert left[0] < far[0] < right[0]                     # the far corner between the sides...
    assert far[1] < left[1] and far[1] < right[1]          # ...and above them: a "^"
    assert 0 < far[0] < 512 and 0 < far[1] < 256           # in view, in the upper half


def test_layouts_are_framed_by_the_fixed_camera(valid_scenes):
    """Every body of every template's first valid scene starts inside the image, the red ball
    with a readable projected radius."""
    for t in TEMPLATES_3D:
        spec, rollout, _ = valid_scenes[t.template_id]
        det = detection_from_spec_3d(spec, rollout.frame_poses[0])
        for obj in det["objects"]:
            box = obj["bbox"]
            assert box["x_min"] > 0 and box["x_max"] < 512, (spec["scene_id"], obj["id"])
            assert box["y_min"] > 0 and box["y_max"] < 512, (spec["scene_id"], obj["id"])
        red = next(o for o in det["objects"] if o["id"] == "red_ball")
        assert 9.0 <= red["size"]["radius_pixels"] <= 30.0, (spec["scene_id"], red["size"])


def test_twelve_templates_thirty_scenes_with_paper_style_ids():
    assert [t.template_id for t in TEMPLATES_3D] == list(range(1, 13))
    assert sum(t.n_variants for t in TEMPLATES_3D) == 30
    spec = TEMPLATES_3D[2].make(np.random.default_rng(0), 1)
    assert spec["scene_id"] == "03_tmpl_01" and spec["dim"] == "3d"


def test_schema_accepts_every_template_variant_and_each_has_a_red_sphere():
    for t in TEMPLATES_3D:
        for v in range(t.n_variants):
            spec = t.make(np.random.default_rng(t.template_id * 100), v)
            validate_spec_3d(spec)
            w, cam = spec["world"], spec["camera"]
            assert (w["n_frames"], w["video_fps"], w["steps_per_frame"]) == (75, 15, 4)
            assert (cam["width"], cam["height"]) == (512, 512)
            assert spec["render"]["background_rgb"] == [255, 255, 255]
            assert any(b["dynamic"] and b["shape"]["type"] == "sphere"
                       and tuple(b["color_rgb"]) == RED_RGB for b in spec["bodies"])


def test_schema_errors_name_the_scene_and_the_field():
    spec = TEMPLATES_3D[0].make(np.random.default_rng(100), 0)
    bad = copy.deepcopy(spec)
    bad["bodies"][0]["shape"]["radius_m"] = -0.2
    with pytest.raises(ValueError) as info:
        validate_spec_3d(bad)
    msg = str(info.value)
    assert spec["scene_id"] in msg and "$.bodies[0].shape.radius_m" in msg and "\n" not in msg
    bad = copy.deepcopy(spec)
    del bad["camera"]["fov_deg"]
    with pytest.raises(ValueError, match=r"\$\.camera\.fov_deg: required"):
        validate_spec_3d(bad)
    bad = copy.deepcopy(spec)
    bad["bodies"][0]["pose"]["quat"] = [0.0, 0.0, 0.5, 0.5]
    with pytest.raises(ValueError, match=r"\$\.bodies\[0\]\.pose\.quat: quaternion"):
        validate_spec_3d(bad)
    bad = copy.deepcopy(spec)
    bad["bodies"][0]["category"] = "rectangle"
    with pytest.raises(ValueError, match=r"\$\.bodies\[0\]\.category"):
        validate_spec_3d(bad)


def test_simulation_is_deterministic_and_the_initial_state_matters(valid_scenes):
    spec, rollout, _ = valid_scenes[5]
    again = simulate_3d(spec)
    assert trajectory_digest_3d(again) == trajectory_digest_3d(rollout)
    assert np.array_equal(again.step_poses, rollout.step_poses)
    assert again.events == rollout.events
    assert rollout.frame_poses.shape == (75, len(spec["bodies"]), 7)
    assert rollout.step_poses.shape == (4 * 74 + 1, len(spec["bodies"]), 7)
    assert list(rollout.frame_steps) == [4 * k for k in range(75)]
    assert np.allclose(rollout.frame_times_s, np.arange(75) / 15)
    assert np.array_equal(rollout.frame_poses[0], rollout.step_poses[0])
    moved = copy.deepcopy(spec)
    moved["bodies"][0]["pose"]["position_m"][0] += 0.01
    assert trajectory_digest_3d(simulate_3d(moved)) != trajectory_digest_3d(rollout)


def test_free_fall_is_cannons_semi_implicit_euler_of_half_g_t_squared():
    spec = copy.deepcopy(TEMPLATES_3D[3].make(np.random.default_rng(400), 0))
    ball = next(b for b in spec["bodies"] if b["id"] == "red_ball")
    ball["pose"]["position_m"] = [0.0, 3.0, 0.0]
    ball["velocity"] = {"linear_m_s": [0.0, 0.0, 0.0], "angular_rad_s": [0.0, 0.0, 0.0]}
    spec["bodies"] = [ball]
    spec["contacts"]["pairs"] = []
    rollout = simulate_3d(spec, n_steps=30)            # 0.5 s, still in the air
    g, dt = 9.82, 1 / 60
    n = np.arange(31)
    t = n * dt
    y = rollout.step_poses[:, 0, 1]
    # cannon integrates v += g dt, then x += v dt: y_n = y0 - g dt² n(n+1)/2 = y0 - g t (t+dt)/2
    assert np.allclose(y, 3.0 - 0.5 * g * t * (t + dt), atol=1e-9, rtol=0)
    # i.e. 0.5 g t² to within the integrator's lag g dt t / 2 (4.1 cm at 0.5 s), to 1e-3 m
    lag = 0.5 * g * dt * t
    assert np.abs((3.0 - y) - (0.5 * g * t ** 2 + lag)).max() < 1e-3
    assert np.allclose(rollout.step_poses[:, 0, [0, 2]], 0.0) and rollout.events == []


def test_each_template_has_a_valid_scene_within_four_draws(valid_scenes):
    for t in TEMPLATES_3D:
        found = valid_scenes[t.template_id]
        assert found is not None, f"template {t.template_id}: no valid scene in 4 draws"
        spec, rollout, _ = found
        assert validity_problems_3d(spec, rollout) == []
        dyn = [i for i, b in enumerate(spec["bodies"]) if b["dynamic"]]
        travel = np.linalg.norm(rollout.frame_poses[-1, dyn, :3] - rollout.frame_poses[0, dyn, :3],
                                axis=1).max()
        assert travel > 0.3, f"{spec['scene_id']}: nothing moves clearly ({travel:.2f} m)"


def test_validity_reasons_fire(valid_scenes):
    spec, rollout, _ = valid_scenes[4]
    assert set(REASONS) == {"overlap", "offscreen", "static", "tunnelling", "speed_cap"}
    sunk = copy.deepcopy(spec)
    red = next(b for b in sunk["bodies"] if b["id"] == "red_ball")
    other = next(b for b in sunk["bodies"] if b["id"] != "red_ball" and b["dynamic"])
    red["pose"]["position_m"] = list(other["pose"]["position_m"])
    assert "overlap" in validity_problems_3d(sunk, simulate_3d(sunk))
    far = copy.deepcopy(spec)
    far["camera"]["look_at"] = [40.0, 0.0, 0.0]
    assert "offscreen" in validity_problems_3d(far, rollout)
    still = copy.deepcopy(rollout)
    still.step_poses = np.repeat(rollout.step_poses[:1], len(rollout.step_poses), axis=0)
    assert validity_problems_3d(spec, still) == ["static"]
    fast = copy.deepcopy(rollout)
    fast.step_poses[5:, 0, 1] -= 2.0
    assert {"tunnelling", "speed_cap"} <= set(validity_problems_3d(spec, fast))


def test_difficulty_features(valid_scenes):
    spec, rollout, _ = valid_scenes[9]  # dominoes: planks topple
    feats = difficulty_features_3d(spec, rollout)
    assert feats["n_bodies"] == len(spec["bodies"]) and feats["n_dynamic"] >= 5
    assert feats["rotation_over_30deg"] and feats["max_rotation_deg"] > 30
    assert feats["n_contacts"] >= 2 and 0.0 <= feats["occlusion"] <= 1.0
    assert feats["sensitivity_px"] >= 0.0 and feats["chaotic"] == (feats["sensitivity_px"] > 16)


def test_detection_schema_and_projection(valid_scenes):
    spec, rollout, _ = valid_scenes[1]
    det = detection_from_spec_3d(spec, rollout.frame_poses[0])
    assert det["image_size"] == {"width": 512, "height": 512}
    assert det["coordinate_system"]["origin"] == "top_left"
    assert [o["id"] for o in det["objects"]] == [b["id"] for b in spec["bodies"]]
    for obj in det["objects"]:
        box = obj["bbox"]
        assert box["x_min"] <= obj["position"]["center_x"] <= box["x_max"]
        assert box["y_min"] <= obj["position"]["center_y"] <= box["y_max"]
    cam = spec["camera"]
    centre = project_points(spec, [cam["look_at"]])[0]
    assert np.allclose(centre, [256.0, 256.0], atol=1e-9)  # the camera looks at the image centre
    above = project_points(spec, [np.add(cam["look_at"], [0.0, 0.5, 0.0])])[0]
    assert above[1] < 256.0  # y up in the world is up in the image


# ------------------------------------------------------------------------------ rendering
@pytest.fixture(scope="module")
def pool():
    from visphy_core.api.assets import assets_installed

    if not assets_installed():
        pytest.skip("browser engine libraries not installed (`python -m visphy_core setup`)")
    from visphy_core.sandbox.browser import BrowserPool

    with BrowserPool() as p:
        yield p


def _red_centroid(frame: np.ndarray) -> tuple[np.ndarray, int]:
    """Centroid and area of the red pixels: red by chromaticity (r above 1.8 times g and b), so
    the ball's shaded side counts as much as its lit side and an anti-aliased edge pixel counts
    when about half covered (the centroid is unbiased to a few hundredths of a pixel)."""
    r, g, b = (frame[..., i].astype(int) for i in range(3))
    mask = (r > 60) & (r > 1.8 * np.maximum(g, b))
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean() + 0.5, ys.mean() + 0.5]), int(mask.sum())


@pytest.mark.browser
def test_replay_is_deterministic_and_matches_the_projection(valid_scenes, pool):
    from visphy_core.infra.video import frame_digest
    from visphy_plugins.engines.threejs import replay_html_3d
    from visphy_plugins.datasets.visphybench.render3d import render_clip_3d

    spec, rollout, _ = valid_scenes[4]  # sphere collision: the red ball is never hidden
    html = replay_html_3d(spec, rollout.frame_poses, 15, 75)
    assert html == replay_html_3d(spec, rollout.frame_poses, 15, 75)
    assert "setupRecording(" in html and "requestAnimationFrame" in html
    a = render_clip_3d(spec, rollout.frame_poses, pool)
    b = render_clip_3d(spec, rollout.frame_poses, pool)
    assert a.shape == (75, 512, 512, 3) and a.dtype == np.uint8
    assert [frame_digest(f) for f in a] == [frame_digest(f) for f in b]
    assert not np.array_equal(a[0], a[-1])  # something moves
    assert tuple(a[0][2, 256]) == (255, 255, 255)  # white sky at the top
    det = detection_from_spec_3d(spec, rollout.frame_poses[0])
    red = next(o for o in det["objects"] if o["id"] == "red_ball")
    for k in (0, 5):
        centroid, n = _red_centroid(a[k])
        want = project_points(spec, rollout.frame_poses[k, 0, :3])[0]
        assert n > 100 and np.hypot(*(centroid - want)) <= 2.0, (k, centroid, want)
    centroid, n = _red_centroid(a[0])
    assert np.hypot(centroid[0] - red["position"]["center_x"],
                    centroid[1] - red["position"]["center_y"]) <= 2.0
    radius = np.sqrt(n / np.pi)
    assert abs(radius - red["size"]["radius_pixels"]) <= 2.0


@pytest.mark.browser
def test_threejs_engine_runs_the_replay_page_unchanged(valid_scenes, pool):
    """The engine's reference program for 3D scenes (same page, engine's trusted template)
    reproduces the ground-truth frames exactly."""
    from visphy_core.api.engine import Program, RenderContract
    from visphy_plugins.engines.threejs import replay_html_3d
    from visphy_plugins.datasets.visphybench.render3d import render_clip_3d
    from visphy_plugins.engines.threejs import ThreeJsEngine

    spec, rollout, _ = valid_scenes[8]
    poses = rollout.frame_poses[:6]
    engine = ThreeJsEngine()
    try:
        result = engine.render(Program("html", replay_html_3d(spec, poses, 15, 6), spec=spec),
                               RenderContract(fps=15, n_frames=6, width=512, height=512,
                                              dim="3d", timeout_s=120))
    finally:
        engine.close()
    assert result.ok, result.error
    assert np.array_equal(result.frames, render_clip_3d(spec, poses, pool))


def _polygon_area_centroid(pts: np.ndarray) -> tuple[float, np.ndarray]:
    x, y = pts[:, 0], pts[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2.0
    cx = ((x + np.roll(x, -1)) * cross).sum() / (6.0 * area)
    cy = ((y + np.roll(y, -1)) * cross).sum() / (6.0 * area)
    return abs(area), np.array([cx, cy])


@pytest.mark.browser
@pytest.mark.slow
def test_rendered_ground_truth_shows_the_simulated_red_ball_where_the_camera_puts_it(
        valid_scenes, pool):
    """Not circular: the cannon-es trajectory, projected through the spec's camera matrix
    (pure numpy), against the three.js frames of the ground-truth renderer. In every frame
    where the red ball is whole on screen and unoccluded (its pixel area within 10 % of its
    projected outline's), the red pixels' centroid is the projected outline's centroid."""
    from visphy_plugins.datasets.visphybench.detection3d import sphere_silhouette
    from visphy_plugins.datasets.visphybench.render3d import render_clip_3d

    checked = 0
    for template_id in (1, 4, 8, 12):
        spec, rollout, _ = valid_scenes[template_id]
        frames = render_clip_3d(spec, rollout.frame_poses, pool)
        red = next(i for i, b in enumerate(spec["bodies"]) if b["id"] == "red_ball")
        radius = spec["bodies"][red]["shape"]["radius_m"]
        errors = []
        for k, frame in enumerate(frames):
            outline = project_points(spec, sphere_silhouette(spec, rollout.frame_poses[k, red, :3],
                                                             radius))
            area, want = _polygon_area_centroid(outline)
            inside = (outline.min() > 1) and (outline.max() < 511)
            centroid, n = _red_centroid(frame)
            if not inside or n < 30 or abs(n - area) > 0.1 * area:
                continue  # off screen, tiny, or partly hidden behind another body
            errors.append(float(np.hypot(*(centroid - want))))
        assert len(errors) >= 20, (template_id, len(errors))
        # sub-pixel on the whole; a frame with a sliver hidden behind another body stays < 2 px
        assert np.median(errors) <= 0.25, (template_id, errors)
        assert max(errors) <= 2.0, (template_id, errors)
        checked += len(errors)
    assert checked >= 120


def _neutral(frame: np.ndarray) -> np.ndarray:
    f = frame.astype(int)
    return np.ptp(f, axis=2) <= 3


@pytest.mark.browser
def test_rendered_look_floor_grey_antialiased_no_shadows(valid_scenes, pool):
    """The published clips' look on a rendered scene: floor grey 151 +- 4, anti-aliased edges
    (the floor's far edge against the white sky has intermediate greys), and no cast shadows
    (the floor around a ball on it is floor grey)."""
    from visphy_plugins.datasets.visphybench.render3d import render_clip_3d

    spec, rollout, _ = valid_scenes[4]  # sphere collision: balls end at rest on the floor
    frames = render_clip_3d(spec, rollout.frame_poses[[0, 74]], pool)
    for frame in frames:
        grey = frame[..., 0][_neutral(frame) & (frame[..., 0] < 200)]
        mode = np.bincount(grey).argmax()
        assert abs(int(mode) - 151) <= 4, mode
        assert np.mean(np.abs(grey.astype(int) - 151) <= 4) > 0.95
    # anti-aliasing: along the far edge of the floor, pixels between floor grey and white
    upper = frames[0][:256]
    edge = _neutral(upper) & (upper[..., 0] > 160) & (upper[..., 0] < 245)
    assert edge.sum() >= 50, edge.sum()
    # no shadow: floor points around every sphere on the floor show floor grey
    last = frames[1]
    checked = 0
    for i, b in enumerate(spec["bodies"]):
        if b["shape"]["type"] != "sphere":
            continue
        x, y, z = rollout.frame_poses[74, i, :3]
        r = b["shape"]["radius_m"]
        if abs(y - r) > 0.02:  # not on the floor
            continue
        angles = np.linspace(0.0, 2.0 * np.pi, 36, endpoint=False)
        ring = np.stack([x + 1.25 * r * np.cos(angles), np.zeros_like(angles),
                         z + 1.25 * r * np.sin(angles)], axis=1)
        for px, py in project_points(spec, ring).astype(int):
            pixel = last[py, px].astype(int)
            if np.ptp(pixel) <= 3:                 # floor, not a body
                assert abs(pixel[0] - 151) <= 4, (b["id"], pixel)
                checked += 1
    assert checked >= 20, checked


@pytest.mark.browser
def test_the_u_container_is_translucent(valid_scenes, pool):
    """Where the container is drawn over the floor, the floor shows through it: the pixel lies
    between the opaque container's colour and the floor grey (same scene rendered with the
    container opaque)."""
    from visphy_plugins.datasets.visphybench.render3d import render_clip_3d

    spec, rollout, _ = valid_scenes[1]
    idx = next(i for i, b in enumerate(spec["bodies"]) if "container" in b["id"])
    assert spec["bodies"][idx]["opacity"] == 0.5
    opaque = copy.deepcopy(spec)
    del opaque["bodies"][idx]["opacity"]
    poses = rollout.frame_poses[:1]
    glass = render_clip_3d(spec, poses, pool)[0].astype(int)
    solid = render_clip_3d(opaque, poses, pool)[0].astype(int)
    det = detection_from_spec_3d(spec, poses[0])["objects"][idx]["bbox"]
    x0, x1 = int(det["x_min"]), int(det["x_max"]) + 1
    y0, y1 = int(det["y_min"]), int(det["y_max"]) + 1
    g, s_ = glass[y0:y1, x0:x1], solid[y0:y1, x0:x1]
    changed = np.abs(g - s_).max(axis=2) > 6
    assert changed.sum() >= 50, changed.sum()
    # through the glass: about half way from the opaque colour to the grey floor behind
    between = (np.minimum(s_, 151) - 3 <= g) & (g <= np.maximum(s_, 151) + 3)
    assert between.all(axis=2)[changed].mean() > 0.8
