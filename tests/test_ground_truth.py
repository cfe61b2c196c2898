"""The Box2D ground truth of the generated mini set: schema, physics, determinism, detection."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from mini_templates import layout_problems, mini_specs

from visphy_core.spec.spec2d import validate_spec
from visphy_plugins.datasets.visphybench.detection import detection_from_spec
from visphy_plugins.datasets.visphybench.loader import load_generated
from visphy_plugins.datasets.visphybench.raster2d import render_frame_2d
from visphy_plugins.physics.box2d import simulate_2d, trajectory_digest


@pytest.fixture(scope="module")
def specs():
    return mini_specs()


def test_mini_specs_validate_and_have_a_red_action_ball(specs):
    assert len(specs) >= 3
    for spec in specs:
        validate_spec(spec)
        assert spec["dim"] == "2d" and spec["world"]["n_frames"] == 17
        assert any(b["color_rgb"] == [243, 79, 70] and b["dynamic"] for b in spec["bodies"])


def test_schema_errors_name_the_scene_and_field(specs):
    bad = copy.deepcopy(specs[0])
    bad["bodies"][0]["shape"]["radius_px"] = -3
    with pytest.raises(ValueError) as info:
        validate_spec(bad)
    message = str(info.value)
    assert specs[0]["scene_id"] in message and "bodies" in message and "\n" not in message


def test_free_fall_advances_by_58_8_px_per_frame_squared(specs):
    spec = copy.deepcopy(specs[0])
    ball = next(b for b in spec["bodies"] if b["category"] == "circle" and b["dynamic"])
    ball["pose"].update(x_px=256.0, y_px=490.0)
    spec["bodies"] = [ball]
    spec["world"]["n_frames"] = 4  # t = 3 s: fallen 265 px, still in the air
    spec["contacts"]["pairs"] = []
    rollout = simulate_2d(spec)
    y = rollout.frame_poses[:, 0, 1]
    second = y[2:] - 2 * y[1:-1] + y[:-2]
    assert np.allclose(second, -58.8, atol=0.05), second


def test_simulation_is_deterministic_and_seeds_matter(specs):
    a, b = simulate_2d(specs[0]), simulate_2d(specs[0])
    assert trajectory_digest(a) == trajectory_digest(b)
    moved = copy.deepcopy(specs[0])
    moved["bodies"][-1]["pose"]["x_px"] += 1.0
    assert trajectory_digest(simulate_2d(moved)) != trajectory_digest(a)


def test_scenes_start_on_screen_without_overlap_and_something_moves(specs):
    for spec in specs:
        assert layout_problems(spec) == []
        rollout = simulate_2d(spec)
        travel = np.abs(rollout.frame_poses[-1, :, :2] - rollout.frame_poses[0, :, :2]).max()
        assert travel > 20, f"{spec['scene_id']}: nothing moves clearly"


def test_detection_centres_agree_with_the_rendered_first_frame(specs):
    for spec in specs:
        rollout = simulate_2d(spec)
        frame = render_frame_2d(spec, rollout.frame_poses[0])
        det = detection_from_spec(spec, rollout.frame_poses[0])
        colours = [tuple(b["color_rgb"]) for b in spec["bodies"]]
        for obj in det["objects"]:
            colour = tuple(obj["color_rgb"])
            if colours.count(colour) != 1 or obj["category"] in ("u_shape", "composite_shape"):
                continue  # shared colours are ambiguous; a jar's centroid is not its bbox centre
            ys, xs = np.nonzero(np.all(frame == colour, axis=-1))
            cx, cy = xs.mean() + 0.5, ys.mean() + 0.5
            assert abs(cx - obj["position"]["center_x"]) <= 2, (spec["scene_id"], obj["id"])
            assert abs(cy - obj["position"]["center_y"]) <= 2, (spec["scene_id"], obj["id"])


def test_build_is_byte_identical_and_seeds_matter(tmp_path):
    from visphy_plugins.datasets.visphybench.build import write_scene
    from visphy_plugins.datasets.visphybench.catalogue import build_catalogue, units

    some = [u for u in units() if u.dim == "2d"][:2]
    first = build_catalogue(seed=0, workers=1, progress=False, only=some)
    again = build_catalogue(seed=0, workers=1, progress=False, only=some)
    other = build_catalogue(seed=1, workers=1, progress=False, only=some)
    assert [e.digest for e in first.entries] == [e.digest for e in again.entries]
    assert [e.digest for e in first.entries] != [e.digest for e in other.entries]
    for entry_a, entry_b in zip(first.entries, again.entries):
        write_scene(entry_a, tmp_path / "a")
        write_scene(entry_b, tmp_path / "b")
    a, b = tmp_path / "a", tmp_path / "b"
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert len(files) >= 14 and files == sorted(p.relative_to(b) for p in b.rglob("*")
                                                if p.is_file())
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


def test_clips_are_encoded_like_the_published_ones_or_exactly(tmp_path):
    """Default: H.264 yuv420p at crf 23 (the published clips'); lossless: frames decode back to
    the rasteriser's pixels bit for bit."""
    import av

    from visphy_core.infra.video import decode_video
    from visphy_plugins.datasets.visphybench.build import write_scene
    from visphy_plugins.datasets.visphybench.catalogue import build_catalogue, units
    from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d

    entry = build_catalogue(seed=0, workers=1, progress=False,
                            only=[u for u in units() if u.dim == "2d"][:1]).entries[0]
    published = write_scene(entry, tmp_path / "pub")
    exact = write_scene(entry, tmp_path / "exact", lossless=True)
    sid = entry.spec["scene_id"]
    assert published["encoding"] == "h264-yuv420p-crf23"
    assert exact["encoding"] == "h264rgb-lossless"
    pub_file = tmp_path / "pub" / "videos" / f"{sid}.mp4"
    with av.open(str(pub_file)) as c:
        assert c.streams.video[0].codec_context.pix_fmt == "yuv420p"
    assert b"crf=23.0" in pub_file.read_bytes()  # x264 writes its settings into the stream
    truth = render_clip_2d(entry.spec, simulate_2d(entry.spec).frame_poses)
    decoded = decode_video(tmp_path / "exact" / "videos" / f"{sid}.mp4")[0]
    assert np.array_equal(decoded, truth)
    lossy = decode_video(pub_file)[0]
    assert not np.array_equal(lossy, truth) and np.abs(lossy.astype(int) - truth).mean() < 2


def test_built_layout_and_loader(mini_root, mini_scenes):
    catalogue = json.loads((mini_root / "catalogue.json").read_text())
    assert len(catalogue["splits"]["mini"]) == len(mini_scenes) >= 3
    scene = mini_scenes[0]
    assert scene.clip.fps == 5 and scene.clip.n_frames == 17
    assert (scene.clip.width, scene.clip.height) == (512, 512)
    assert scene.reference_frames().shape == (17, 512, 512, 3)
    assert scene.key_frame(10).shape == (512, 512, 3)
    spec = scene.spec
    assert spec["digest_sha256"] == trajectory_digest(simulate_2d(spec))
    traj = scene.trajectory
    assert traj["frame_poses"].shape[:2] == (17, len(spec["bodies"]))
    assert list(traj["frame_steps"][:3]) == [1, 61, 121]


def test_loader_names_the_missing_or_malformed_file(tmp_path, mini_root):
    import shutil

    root = tmp_path / "bench"
    shutil.copytree(mini_root, root)
    sid = json.loads((root / "metadata.jsonl").read_text().splitlines()[0])["scene_id"]
    (root / "videos" / f"{sid}.mp4").unlink()
    with pytest.raises(FileNotFoundError, match=f"videos/{sid}.mp4"):
        load_generated(root)
    (root / "metadata.jsonl").write_text("{not json\n")
    with pytest.raises(ValueError, match="metadata.jsonl line 1"):
        load_generated(root)
