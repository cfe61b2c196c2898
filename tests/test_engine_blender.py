"""The blender engine: extraction and validation classes, the render contract (frame count, size,
frame <-> time mapping), determinism, failure classes, and the reference program vs ground truth.

Rendering tests need Blender's own virtual environment (`scripts/setup_blender.sh`); they are
skipped with that hint when it is missing. Extraction/validation tests always run.
"""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest

from visphy_core.api.engine import FailureClass, Program, ProgramRejected, RenderContract
from visphy_core.infra.video import frame_digest
from visphy_plugins.engines.blender import SETUP_HINT, BlenderEngine, find_blender_python

pytestmark = pytest.mark.blender

needs_blender = pytest.mark.skipif(
    find_blender_python() is None,
    reason="Blender venv missing: run scripts/setup_blender.sh (or set VISPHY_BLENDER_PYTHON)")

CONTRACT = RenderContract(fps=5, n_frames=5, width=96, height=64, timeout_s=60)
RED = (243, 79, 70)


@pytest.fixture(scope="module")
def engine():
    return BlenderEngine()


def bpy_program(body: str) -> Program:
    return Program("python", "import bpy\n" + textwrap.dedent(body))


# A 2D-style program written the way the instructions ask: ortho camera in pixel units, flat
# colours, one keyframe per frame read from the preset clock. The red square's left edge sits at
# x = 10 + 12 * t * fps px, so contract frame k must show it at column 10 + 12 k.
SQUARE = """
import math
scene = bpy.context.scene
W, H = scene.render.resolution_x, scene.render.resolution_y
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
scene.collection.objects.link(cam)
cam.data.type = "ORTHO"; cam.data.ortho_scale = W
cam.location = (W / 2, H / 2, 100)
scene.camera = cam
scene.world = bpy.data.worlds.new("w"); scene.world.color = (1, 1, 1)
scene.display.shading.light = "FLAT"
scene.display.shading.color_type = "MATERIAL"
scene.display.render_aa = "OFF"
def lin(c):
    c /= 255
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4
mat = bpy.data.materials.new("red"); mat.diffuse_color = (lin(243), lin(79), lin(70), 1)
mesh = bpy.data.meshes.new("sq")
mesh.from_pydata([(0, 0, 0), (8, 0, 0), (8, 8, 0), (0, 8, 0)], [], [(0, 1, 2, 3)])
mesh.materials.append(mat)
sq = bpy.data.objects.new("sq", mesh); scene.collection.objects.link(sq)
fps = scene.render.fps / scene.render.fps_base
for f in range(scene.frame_start, scene.frame_end + 1):
    t = (f - scene.frame_start) / fps
    sq.location = (10 + 12 * t * FPS_SCALE, 20, 0)
    sq.keyframe_insert("location", frame=f)
"""


def square_program(script_fps: int | None = None) -> Program:
    body = SQUARE.replace("FPS_SCALE", "5")
    if script_fps is not None:  # the script picks its own frame rate: visphy re-times it
        body = body.replace("fps = scene.render.fps",
                            f"scene.render.fps = {script_fps}; scene.frame_end = 200\n"
                            "fps = scene.render.fps")
    return bpy_program(body)


def red_left_edge(frame: np.ndarray) -> int:
    ys, xs = np.nonzero(np.all(frame == RED, axis=-1))
    return int(xs.min())


# ------------------------------------------------------------------- extraction / validation


def test_extracts_the_python_block_and_the_spec(engine):
    reply = ("The ball falls.\n```json\n{\"objects\": []}\n```\n"
             "```python\nimport bpy\nprint('hi')\n```\n")
    program = engine.extract(reply)
    assert program.language == "python"
    assert program.source.startswith("import bpy")
    assert program.spec == {"objects": []}
    engine.validate(program)


def test_an_unlabelled_block_that_imports_bpy_counts(engine):
    program = engine.extract("Analysis.\n```\nimport bpy, math\nx = 1\n```\n")
    assert "x = 1" in program.source


@pytest.mark.parametrize("reply, failure", [
    ("", FailureClass.NO_CODE),
    ("Just prose, no code.", FailureClass.NO_CODE),
    ("```html\n<html><script>1</script></html>\n```", FailureClass.WRONG_LANGUAGE),
    ("```python\nimport bpy\nx = (", FailureClass.TRUNCATED),
])
def test_extraction_failure_classes(engine, reply, failure):
    with pytest.raises(ProgramRejected) as info:
        engine.extract(reply)
    assert info.value.failure is failure


@pytest.mark.parametrize("source, failure, text", [
    ("import bpy\ndef f(:\n    pass\n", FailureClass.SYNTAX_ERROR, "line 2"),
    ("import matplotlib.pyplot as plt\nplt.plot([1, 2])\n", FailureClass.WRONG_LANGUAGE, "bpy"),
    ("   \n", FailureClass.NO_CODE, "empty"),
])
def test_validation_failure_classes(engine, source, failure, text):
    with pytest.raises(ProgramRejected) as info:
        engine.validate(Program("python", source))
    assert info.value.failure is failure
    assert text in str(info.value)


@pytest.mark.parametrize("source", ["import bpy", "import math, bpy\n", "from bpy import data",
                                    "if True:\n    import bpy.types\n"])
def test_every_way_of_importing_bpy_validates(engine, source):
    assert engine.validate(Program("python", source)) is None  # accepted: no ProgramRejected
    # the import of bpy is what it accepts: the same program importing another module is not
    # a Blender script
    with pytest.raises(ProgramRejected) as info:
        engine.validate(Program("python", source.replace("bpy", "numpy")))
    assert info.value.failure is FailureClass.WRONG_LANGUAGE


def test_instructions_differ_by_dimension(engine):
    two, three = engine.instructions("2d"), engine.instructions("3d")
    assert "bpy" in two and "ORTHO" in two and "perspective" in three and two != three


def test_missing_venv_is_an_infra_error(monkeypatch, tmp_path):
    monkeypatch.delenv("VISPHY_BLENDER_PYTHON", raising=False)
    monkeypatch.setenv("VISPHY_BLENDER_VENV", str(tmp_path / "no-venv"))
    result = BlenderEngine({"python": str(tmp_path / "nope" / "python")}).render(
        square_program(), CONTRACT)
    assert result.failure is FailureClass.INFRA_ERROR and result.error == SETUP_HINT


# --------------------------------------------------------------------------------- rendering


@needs_blender
def test_renders_exactly_n_frames_at_the_contract_size_and_times(engine):
    result = engine.render(square_program(), CONTRACT)
    assert result.ok, (result.error, result.logs[-5:])
    assert result.frames.shape == (5, 64, 96, 3) and result.frames.dtype == np.uint8
    # frame k shows t = k / fps: the square moves 12 px per frame, exact PHYRE colour, no AA
    assert [red_left_edge(f) for f in result.frames] == [10, 22, 34, 46, 58]
    assert {tuple(c) for c in np.unique(result.frames[0].reshape(-1, 3), axis=0)} == {
        RED, (255, 255, 255)}


@needs_blender
@pytest.mark.parametrize("script_fps", [10, 7])
def test_a_script_with_its_own_fps_is_retimed_to_the_contract(engine, script_fps):
    # the script animates at its own fps (keyframes every 1 / script_fps s); the clip is 5 fps:
    # frame k of the clip is Blender frame 1 + k * script_fps / 5 (10 fps: 1 + 2k; 7 fps: sub-
    # frames 1 + 1.4k), so the motion per clip frame is unchanged
    result = engine.render(square_program(script_fps=script_fps), CONTRACT)
    assert result.ok, result.error
    assert [red_left_edge(f) for f in result.frames] == [10, 22, 34, 46, 58]


@needs_blender
def test_same_program_gives_identical_frames(engine):
    program = bpy_program(SQUARE.replace("FPS_SCALE", "5") + textwrap.dedent("""
        import random
        sq.location.y = 10 + random.random() * 30   # seeded by the contract
        sq.keyframe_insert("location", frame=1)
    """))
    a = engine.render(program, CONTRACT)
    b = engine.render(program, CONTRACT)
    assert a.ok and b.ok
    assert [frame_digest(f) for f in a.frames] == [frame_digest(f) for f in b.frames]


@needs_blender
def test_cycles_is_deterministic():
    program = square_program()
    engine = BlenderEngine({"render_engine": "cycles", "samples": 4})
    contract = RenderContract(fps=5, n_frames=2, width=32, height=32, timeout_s=60)
    a, b = engine.render(program, contract), engine.render(program, contract)
    assert a.ok, (a.error, a.logs[-5:])
    assert [frame_digest(f) for f in a.frames] == [frame_digest(f) for f in b.frames]


@needs_blender
@pytest.mark.parametrize("body, failure, text", [
    ("x = 1\nraise ValueError('the ramp is missing')\n", FailureClass.RUNTIME_ERROR,
     "ValueError: the ramp is missing (program.py line 3)"),
    ("def f(:\n", FailureClass.SYNTAX_ERROR, "SyntaxError"),
    ("cube = bpy.data.objects['Cube']\n", FailureClass.RUNTIME_ERROR, "KeyError"),
    ("bpy.ops.mesh.primitive_cube_add()\n", FailureClass.RUNTIME_ERROR, "no camera"),
    (SQUARE.replace("FPS_SCALE", "5") + "def boom(scene, *_):\n    raise RuntimeError('handler "
     "broke')\nbpy.app.handlers.frame_change_pre.append(boom)\n", FailureClass.RUNTIME_ERROR,
     "frame_change_pre handler"),
    ("cam = bpy.data.objects.new('c', bpy.data.cameras.new('c'))\n"
     "bpy.context.scene.collection.objects.link(cam)\nbpy.context.scene.camera = cam\n",
     FailureClass.BLANK_OUTPUT, "one flat colour"),
])
def test_failure_classes(engine, body, failure, text):
    result = engine.render(bpy_program(body), CONTRACT)
    assert result.failure is failure, (result.error, result.logs[-5:])
    assert text in result.error
    assert result.frames is None


@needs_blender
def test_a_runtime_error_while_rendering_keeps_the_frames_before_it(engine):
    # the handler breaks at Blender frame 3 (clip frame 2): clip frames 0 and 1 were rendered
    body = (SQUARE.replace("FPS_SCALE", "5") + "def boom(scene, *_):\n"
            "    if scene.frame_current >= 3:\n        raise RuntimeError('late break')\n"
            "bpy.app.handlers.frame_change_pre.append(boom)\n")
    result = engine.render(bpy_program(body), CONTRACT)
    assert result.failure is FailureClass.RUNTIME_ERROR and "late break" in result.error
    assert result.flags == ["partial_clip"] and result.frames is None
    assert result.partial_frames.shape == (2, 64, 96, 3)
    assert [red_left_edge(f) for f in result.partial_frames] == [10, 22]
    whole = engine.render(square_program(), CONTRACT)
    assert whole.flags == [] and np.array_equal(result.partial_frames, whole.frames[:2])


@needs_blender
def test_an_endless_script_times_out(engine):
    contract = RenderContract(fps=5, n_frames=3, width=32, height=32, timeout_s=8)
    result = engine.render(bpy_program("while True:\n    pass\n"), contract)
    assert result.failure is FailureClass.TIMEOUT
    assert "8 s" in result.error and result.wall_s < 30


@needs_blender
def test_network_access_is_a_sandbox_violation(engine):
    from visphy_core.sandbox.process import isolation_available

    if not isolation_available()[0]:
        pytest.skip("no bubblewrap sandbox here")
    result = engine.render(bpy_program(
        "import socket\nsocket.create_connection(('10.1.2.3', 80), timeout=3)\n"), CONTRACT)
    assert result.failure is FailureClass.SANDBOX_VIOLATION, result.error
    assert "network access attempted" in result.error
    assert result.isolation.startswith("bwrap:") and "netns" in result.isolation
    assert result.logs[0].startswith(f"sandbox: {result.isolation};")


@needs_blender
def test_refused_sandbox_is_an_infra_error(engine, monkeypatch):
    from visphy_core.sandbox import process as sp

    monkeypatch.setattr(sp, "_probe", lambda: (None, "bubblewrap (bwrap) is not installed"))
    monkeypatch.delenv(sp.ALLOW_UNISOLATED_ENV, raising=False)
    result = engine.render(square_program(), CONTRACT)
    assert result.failure is FailureClass.INFRA_ERROR
    assert "bubblewrap" in result.error and "allow_unisolated" in result.error


@needs_blender
def test_memory_limit_is_a_resource_limit():
    eng = BlenderEngine({"memory_mb": 1500})
    result = eng.render(bpy_program("x = bytearray(8 * 1024 ** 3)\n"),
                        RenderContract(fps=5, n_frames=3, width=32, height=32, timeout_s=30))
    assert result.failure is FailureClass.RESOURCE_LIMIT, (result.error, result.logs[-3:])
    assert "memory limit" in result.error


@needs_blender
def test_planted_symlinks_are_not_followed(engine, tmp_path):
    secret = tmp_path / "secret.json"
    secret.write_text('{"status": "runtime_error", "error": "HOST-SECRET"}')
    secret.chmod(0o644)
    body = (f"import os, json\nos.symlink({str(secret)!r}, 'result.json')\n"
            "os._exit(0)\n")
    result = engine.render(bpy_program(body), CONTRACT)
    assert result.failure is not None and "HOST-SECRET" not in (result.error or "")
    assert not any("HOST-SECRET" in line for line in result.logs)


def test_render_engine_is_an_enum_in_the_schema():
    from omegaconf import OmegaConf
    from omegaconf.errors import ValidationError

    from visphy_plugins.engines.blender import BlenderConfig, RenderEngine, _engine_name

    cfg = OmegaConf.structured(BlenderConfig)
    cfg.render_engine = "cycles"
    assert cfg.render_engine is RenderEngine.cycles and _engine_name(cfg) == "cycles"
    with pytest.raises(ValidationError):
        cfg.render_engine = "cyclez"
    assert "disk_mb" in cfg
    identity = BlenderEngine(cfg).cache_identity()
    assert identity.startswith(f"blender@{BlenderEngine.version}:cycles:")


# ------------------------------------------------------------------------ reference program


@pytest.fixture(scope="module")
def jar_scene(tmp_path_factory):
    """A hand-made 2D mini scene (ball into a jar: circle, bars, a compound jar), its spec and
    trajectory written the way a generated dataset stores them, plus its exact reference frames."""
    from mini_templates import mini_scenes

    from visphy_core.api.scene import Scene
    from visphy_core.infra.video import ClipInfo
    from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d

    spec, rollout = mini_scenes()[1]
    d = tmp_path_factory.mktemp("blender_scene")
    (d / "spec.json").write_text(json.dumps(spec))
    np.savez(d / "traj.npz", body_ids=np.array(rollout.body_ids, dtype=str),
             frame_poses=rollout.frame_poses)
    n, (w, h) = len(rollout.frame_poses), spec["world"]["units"]["canvas_px"]
    scene = Scene(scene_id=spec["scene_id"], dim="2d",
                  clip=ClipInfo(fps=float(spec["world"]["video_fps"]), n_frames=n, width=w,
                                height=h),
                  video_path=d / "unused.mp4", spec_path=d / "spec.json",
                  trajectory_path=d / "traj.npz")
    order = [list(rollout.body_ids).index(b["id"]) for b in spec["bodies"]]
    return scene, render_clip_2d(spec, rollout.frame_poses[:, order])


@needs_blender
def test_reference_program_tracks_ground_truth(engine, jar_scene):
    scene, truth = jar_scene
    program = engine.program_from_spec(scene)
    engine.validate(program)
    result = engine.render(program, RenderContract.for_scene(scene))
    assert result.ok, (result.error, result.logs[-5:])
    assert result.frames.shape == truth.shape
    assert result.flags == []
    # same fill rule as the exact rasteriser: at most a few edge pixels differ per frame
    differing = np.any(result.frames != truth, axis=-1).sum(axis=(1, 2))
    assert differing.max() <= 20, differing
    colours = [tuple(b["color_rgb"]) for b in scene.spec["bodies"]]
    for body in scene.spec["bodies"]:
        rgb = tuple(body["color_rgb"])
        if colours.count(rgb) != 1:
            continue
        for k in range(len(truth)):
            got = np.argwhere(np.all(result.frames[k] == rgb, axis=-1)).mean(axis=0)
            want = np.argwhere(np.all(truth[k] == rgb, axis=-1)).mean(axis=0)
            assert np.hypot(*(got - want)) < 0.5, (body["id"], k)


@needs_blender
def test_reference_program_3d_camera_and_shapes(engine, tmp_path):
    """A hand-written 3D scene (sphere, box, wedge, compound; the spec's y-up axes): the red
    sphere's centre lands where the spec's pinhole camera projects it."""
    from visphy_core.api.scene import Scene
    from visphy_core.infra.video import ClipInfo

    cam = {"type": "perspective", "fov_deg": 45.0, "near": 0.1, "far": 100.0,
           "position": [0.5, 2.0, 6.0], "look_at": [0.0, 0.5, 0.0], "up": [0.0, 1.0, 0.0],
           "width": 128, "height": 96}
    q0 = [0.0, 0.0, 0.0, 1.0]
    bodies = [
        {"id": "red_ball", "color_rgb": [243, 79, 70],
         "shape": {"type": "sphere", "radius_m": 0.3}},
        {"id": "green_box", "color_rgb": [107, 206, 187],
         "shape": {"type": "box", "size_m": [0.5, 0.5, 0.5]}},
        {"id": "black_ramp", "color_rgb": [0, 0, 0],
         "shape": {"type": "wedge", "length_m": 1.5, "height_m": 0.6, "width_m": 0.8}},
        {"id": "blue_jar", "color_rgb": [24, 119, 242], "shape": {"type": "compound", "parts": [
            {"shape": {"type": "box", "size_m": [0.8, 0.1, 0.4]}, "offset_m": [0, -0.2, 0],
             "quat": q0},
            {"shape": {"type": "sphere", "radius_m": 0.1}, "offset_m": [0.3, 0.1, 0],
             "quat": q0}]}},
    ]
    spec = {"scene_id": "99_tmpl_00", "dim": "3d", "camera": cam, "bodies": bodies,
            "render": {"background_rgb": [255, 255, 255], "shadows": True},
            "world": {"floor": {"y": 0.0, "color_rgb": [150, 150, 150], "size_m": 60.0}}}
    ball_path = [[-1.0 + 0.5 * k, 1.5 - 0.2 * k, 0.0] for k in range(4)]
    frames = [[p + q0, [1.0, 0.25, 0.5] + q0, [-0.8, 0.2, -1.0] + q0, [0.5, 0.25, -2.0] + q0]
              for p in ball_path]
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    np.savez(tmp_path / "traj.npz", body_ids=np.array([b["id"] for b in bodies]),
             frame_poses=np.array(frames))
    scene = Scene(scene_id="99_tmpl_00", dim="3d",
                  clip=ClipInfo(fps=15.0, n_frames=4, width=128, height=96),
                  video_path=tmp_path / "unused.mp4", spec_path=tmp_path / "spec.json",
                  trajectory_path=tmp_path / "traj.npz")
    result = engine.render(engine.program_from_spec(scene), RenderContract.for_scene(scene))
    assert result.ok, (result.error, result.logs[-5:])
    assert result.frames.shape == (4, 96, 128, 3)
    # pinhole projection of the ball centre (three.js / Blender camera conventions)
    eye, target = np.array(cam["position"]), np.array(cam["look_at"])
    z = (eye - target) / np.linalg.norm(eye - target)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    f = 1.0 / np.tan(np.radians(cam["fov_deg"]) / 2)
    for k, frame in enumerate(result.frames):
        v = np.array(ball_path[k]) - eye
        cx, cy, cz = v @ x, v @ y, v @ z
        want_col = (1 + f * cx / -cz * 96 / 128) / 2 * 128
        want_row = (1 - f * cy / -cz) / 2 * 96
        f32 = frame.astype(int)
        rows, cols = np.nonzero((f32[..., 0] > 120) & (f32[..., 1] < 100) & (f32[..., 2] < 100))
        assert len(rows) > 50
        assert abs(cols.mean() + 0.5 - want_col) < 1.0 and abs(rows.mean() + 0.5 - want_row) < 1.0
    assert len({frame_digest(f) for f in result.frames}) == 4  # it moves
