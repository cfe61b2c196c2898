"""Native-drawing reference programs: `Engine.native_program_from_spec` and the
oracle's ``model.style=native`` (plugins/engines/native.py, plugins/engines/templates/*_native_*).

The exact reference programs reproduce the benchmark's alias-free raster, so the exact oracle is
(nearly) byte-identical across engines and cross-engine oracle numbers test plumbing. The native
ones draw the same ground-truth poses with each engine's own primitives and default
anti-aliasing. Here, on two scenes of the mini split, for every engine: the native clip renders,
is really drawn (not byte-identical to the exact oracle's, yet close: PSNR ≥ 30 dB between
them), the object tracks stay within 2 px of the ground truth (the exact oracle scores ≈ 0) and
the headline physics score (still clip = 0, ideal values as ceilings) stays ≥ 0.8. A CLI run
(`model=oracle model.style=native`) checks the wiring and the run's own headline.
"""

from __future__ import annotations

import json
import math
import types

import numpy as np
import pytest

from conftest import run_cli
from visphy_core.api.engine import Engine, RenderContract
from visphy_plugins.engines.native import native_payload, union_outline

SCENES = (0, 1)           # two of the mini split's four 2D scenes
TRACK_BOUND_PX = 2.0      # mean track position error of the native clip (the exact one: ≈ 0)
HEADLINE_MIN = 0.8
PSNR_MIN_DB = 30.0        # native vs exact: drawn differently, not something else


# ------------------------------------------------------------------------------ helpers
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(((a.astype(np.float64) - b.astype(np.float64)) ** 2).mean())
    return math.inf if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)


def headline(scene, ref: np.ndarray, gen: np.ndarray, tmp_path) -> tuple[float, dict]:
    """The scene's physics score with the still clip (the first frame held) as floor and the
    metrics' ideal values as ceilings; and the generated clip's component values."""
    from visphy_core.api.registry import get_registry
    from visphy_core.infra.cache import Cache
    from visphy_core.scoring.headline import Headline, scene_headline
    from visphy_core.scoring.score import score_scene

    head = Headline()
    reg = get_registry()
    # the components, and the object tracks' error the test bounds too
    metrics = [reg.get("metrics", name) for name in (*head.components, "track_pos_err")]
    cache = Cache(tmp_path / "cache", enabled=False)
    still = np.repeat(ref[:1], len(ref), axis=0)

    def values(clip):
        scores, _ = score_scene(scene, ref, clip, metrics, None, scene.spec, cache)
        return {m.name: scores.get(m.name) for m in metrics}  # the time-honest view

    got = values(gen)
    value, _ = scene_headline(head, metrics, got, values(still), {})
    return value, got


def check_native(engine: Engine, scenes, tmp_path) -> list[dict]:
    rows = []
    for scene in scenes:
        ref = scene.reference_frames()
        contract = RenderContract.for_scene(scene, timeout_s=180)
        exact = engine.render(engine.program_from_spec(scene), contract)
        native_program = engine.native_program_from_spec(scene)
        engine.validate(native_program)
        native = engine.render(native_program, contract)
        assert exact.ok and native.ok, (scene.scene_id, native.failure, native.error)
        assert native.frames.shape == ref.shape
        assert not np.array_equal(native.frames, exact.frames), "native = exact: not drawn"
        between = psnr(native.frames, exact.frames)
        assert PSNR_MIN_DB <= between < 60.0, (scene.scene_id, between)
        value, parts = headline(scene, ref, native.frames, tmp_path)
        assert parts["track_pos_err"] <= TRACK_BOUND_PX, (scene.scene_id, parts)
        assert value is not None and value >= HEADLINE_MIN, (scene.scene_id, value, parts)
        rows.append({"scene": scene.scene_id, "psnr_vs_exact": between, "headline": value,
                     **parts})
    return rows


@pytest.fixture(scope="module")
def scenes(mini_scenes):
    return [mini_scenes[i] for i in SCENES]


# ------------------------------------------------------------------------------ no renderer
def test_a_compound_is_drawn_as_the_outline_of_its_abutting_parts():
    base = [[-36.0, -5.0], [36.0, -5.0], [36.0, 5.0], [-36.0, 5.0]]
    left = [[-36.0, 5.0], [-26.0, 5.0], [-26.0, 61.0], [-36.0, 61.0]]
    right = [[26.0, 5.0], [36.0, 5.0], [36.0, 61.0], [26.0, 61.0]]
    outline = union_outline([base, left, right])
    assert outline is not None and len(outline) == 8          # a U: 8 corners, no collinear
    area = sum(p[0] * q[1] - q[0] * p[1]
               for p, q in zip(outline, outline[1:] + outline[:1])) / 2
    assert area == pytest.approx(72 * 10 + 2 * 10 * 56)        # CCW, the parts' total area
    assert {tuple(p) for p in outline} == {(-36, -5), (36, -5), (36, 61), (26, 61), (26, 5),
                                           (-26, 5), (-26, 61), (-36, 61)}
    # overlapping or disjoint parts make no single outline: the programs draw the parts
    assert union_outline([[[0, 0], [2, 0], [2, 2], [0, 2]], [[1, 1], [3, 1], [3, 3], [1, 3]]]) \
        is None
    assert union_outline([[[0, 0], [1, 0], [1, 1], [0, 1]], [[2, 0], [3, 0], [3, 1], [2, 1]]]) \
        is None


def test_the_native_payload_is_the_replay_payload_plus_outlines(scenes):
    from visphy_core.spec.replay import replay_payload

    for scene in scenes:
        exact, native = replay_payload(scene), native_payload(scene)
        assert native["frame_poses"] == exact["frame_poses"] and native["style"] == "native"
        for a, b in zip(exact["bodies"], native["bodies"]):
            assert {k: v for k, v in b.items() if k != "outline"} == a
            assert ("outline" in b) == ("polygons" in a)    # every non-circle is one polygon


def test_engines_declare_native_programs_and_3d_falls_back_to_the_exact_one():
    from visphy_plugins.engines.blender import BlenderEngine
    from visphy_plugins.engines.manim import ManimEngine
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    class Bare(Engine):  # an engine that declares no native program
        name = "bare"
        extract = validate = render = program_from_spec = lambda *a: None

    with pytest.raises(NotImplementedError, match="no native reference program"):
        Bare().native_program_from_spec(None)
    scene3d = types.SimpleNamespace(dim="3d", scene_id="x_3d", spec={}, trajectory={})
    for cls in (ThreeJsEngine, BlenderEngine):   # the 3D exact program already draws meshes
        eng = cls()
        eng.program_from_spec = lambda scene: "the exact 3D program"
        assert eng.native_program_from_spec(scene3d) == "the exact 3D program"
    for cls in (P5Engine, SvgEngine, ManimEngine):
        with pytest.raises(NotImplementedError, match="3D"):
            cls().native_program_from_spec(scene3d)


def test_the_oracle_answers_with_the_program_of_its_style(scenes):
    from omegaconf import OmegaConf

    from visphy_core.api.model import OutputContract, PrivilegedRequest
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.models.oracle import OracleConfig, OracleModel

    cfg = OmegaConf.structured(OracleConfig(name="oracle"))
    exact = OracleModel(cfg)
    assert exact.style == "exact"
    # the exact oracle keeps its identity (cached replies stay valid); native has its own
    assert exact.identity() == OracleModel(OmegaConf.create({"name": "oracle"})).identity()
    cfg_native = OmegaConf.structured(OracleConfig(name="oracle"))
    cfg_native.style = "native"
    native = OracleModel(cfg_native)
    assert native.identity() != exact.identity()
    with pytest.raises(Exception, match="exact, native"):
        cfg_native.style = "vector"
    engine, scene = P5Engine(), scenes[0]
    c = scene.clip
    request = PrivilegedRequest(scene_id=scene.scene_id, prompt="", images=[], detection=None,
                                engine_name="p5", language="html",
                                output=OutputContract(c.fps, c.n_frames, c.width, c.height),
                                scene=scene, engine=engine)
    text = native.generate(request).text
    assert "beginShape" in text and "loadPixels" not in text
    assert "loadPixels" in exact.generate(request).text


# ------------------------------------------------------------------------------ renders
@pytest.mark.browser
@pytest.mark.parametrize("name", ["threejs", "p5", "svg"])
def test_browser_native_reference_is_drawn_and_scores_near_the_exact_oracle(name, scenes,
                                                                             tmp_path):
    from visphy_plugins.engines.browser_base import close_shared_pool
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    engine = {"threejs": ThreeJsEngine, "p5": P5Engine, "svg": SvgEngine}[name]()
    try:
        check_native(engine, scenes, tmp_path)
    finally:
        close_shared_pool()


@pytest.mark.manim
def test_manim_native_reference_is_drawn_and_scores_near_the_exact_oracle(scenes, tmp_path):
    from visphy_plugins.engines.manim import ManimEngine, manim_available

    ok, why = manim_available()
    if not ok:
        pytest.skip(why)
    engine = ManimEngine()
    try:
        check_native(engine, scenes, tmp_path)
    finally:
        engine.close()


@pytest.mark.blender
def test_blender_native_reference_is_drawn_and_scores_near_the_exact_oracle(scenes, tmp_path):
    from visphy_plugins.engines.blender import BlenderEngine, find_blender_python

    if find_blender_python() is None:
        pytest.skip("Blender venv missing: run scripts/setup_blender.sh")
    check_native(BlenderEngine(), scenes, tmp_path)


@pytest.mark.browser
def test_a_run_of_the_native_oracle_scores_the_headline(visphy_home, mini_scenes):
    """``model=oracle model.style=native`` through the CLI: the run records the style, the
    programs are the native ones and the run's headline stays ≥ 0.8."""
    scene_id = mini_scenes[SCENES[0]].scene_id
    run_cli("model=oracle", "model.style=native", "engine=p5", "dataset=mini",
            f"dataset.scenes=[{scene_id}]",
            "metrics.names=[spatiotemporal_iou_tol,weighted_spatial_iou_tol,track_pos_err]",
            "metrics.spec_track=false", "tracking=none", "run.progress=false", home=visphy_home)
    run_dir = max((visphy_home / "runs").iterdir(), key=lambda p: p.stat().st_mtime)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["headline"]["n"] == 1 and summary["headline"]["mean"] >= HEADLINE_MIN
    program = next((run_dir / "scenes").glob("*/program.html")).read_text()
    assert "beginShape" in program and "native reference program" in program
    assert "style: native" in (run_dir / "config.yaml").read_text()
