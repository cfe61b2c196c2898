"""What an engine does to a model's program is recorded, not hidden: library substitutions,
a missing recording call, a resized canvas and the partial clip of a runtime error become row
flags (`RenderFlag`) with their evidence in the render log, survive the render cache, and a page
blocked from its library names the blocked request in its failure detail.

The browser tests run real pages in headless Chromium (small clips: 128², 9 frames at 5 fps);
the pipeline tests use a stand-in engine.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from visphy_core.api.engine import (
    Engine,
    FailureClass,
    Program,
    RenderContract,
    RenderFlag,
    RenderResult,
)
from visphy_core.execute.pipeline import render_cached
from visphy_core.infra.cache import Cache
from visphy_core.infra.video import decode_video

CONTRACT = RenderContract(fps=5, n_frames=9, width=128, height=128, timeout_s=30)

P5_TAG = '<script src="https://cdn.jsdelivr.net/npm/p5@1.11.1/lib/p5.min.js"></script>'


def p5_page(head: str = P5_TAG, record: bool = True, size: int = 128, draw_extra: str = "") -> str:
    """A p5 sketch: a blue disc moving right 2 px per draw() on white."""
    call = "setupRecording(c.elt, 1800);" if record else ""
    return f"""<!DOCTYPE html><html><head>{head}</head><body><script>
let x = 10;
function setup() {{ const c = createCanvas({size}, {size}); {call} noStroke(); }}
function draw() {{ background(255); fill(0, 0, 255); circle(x, {size} / 2, 20); x += 2;
  {draw_extra} }}
</script></body></html>"""


# ------------------------------------------------------------------------ versions (no browser)

def test_requested_versions_are_read_from_cdn_urls():
    from visphy_plugins.engines.browser_base import requested_version, same_version

    assert requested_version("https://cdn.jsdelivr.net/npm/three@0.160.0/build/three.module.js") \
        == "0.160.0"
    assert requested_version("https://cdnjs.cloudflare.com/ajax/libs/p5.js/1.9.0/p5.min.js") \
        == "1.9.0"
    assert requested_version("https://cdnjs.cloudflare.com/ajax/libs/three.js/r128/three.min.js") \
        == "0.128"
    assert requested_version("https://esm.sh/v135/three@^0.160.0") == "0.160.0"
    assert requested_version("https://unpkg.com/three/build/three.module.js") is None
    assert requested_version("https://unpkg.com/three@latest/build/three.module.js") is None
    assert requested_version("https://threejs.org/build/three.module.js") is None
    assert requested_version("js/three.min.js") is None
    assert same_version("0.160.0", "0.160.1") and same_version("0.160", "0.160.1")
    assert same_version("1", "1.11.11") and not same_version("1.9.0", "1.11.11")
    assert not same_version("0.160.0", "0.187.0") and not same_version("0.19.0", "0.20.0")


def test_vendored_versions_come_from_the_lock_file():
    from visphy_plugins.engines.assets import BROWSER_ASSETS
    from visphy_plugins.engines.browser_base import THREE_ESM, served_version

    lock = json.loads((BROWSER_ASSETS.source / "package-lock.json").read_text())["packages"]
    assert served_version("/vendor/three.min.js") == ("three", lock["node_modules/three"]
                                                      ["version"])
    assert served_version(THREE_ESM) == ("three", lock["node_modules/three-esm"]["version"])
    assert served_version("/vendor/matter.min.js")[1] == lock["node_modules/matter-js"]["version"]
    assert served_version("/vendor/elsewhere.js") is None


# ------------------------------------------------------------------------ browser engines

@pytest.fixture(scope="module")
def engines():
    from visphy_plugins.engines.browser_base import close_shared_pool
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    yield {"threejs": ThreeJsEngine(), "p5": P5Engine(), "svg": SvgEngine()}
    close_shared_pool()


def render(engine, html: str, contract: RenderContract = CONTRACT) -> RenderResult:
    return engine.render(Program("html", html), contract)


@pytest.mark.browser
def test_reference_style_page_has_no_flags(engines):
    result = render(engines["p5"], p5_page())
    assert result.ok, (result.error, result.logs[:5])
    assert result.flags == []
    assert any("library served from vendor: https://cdn.jsdelivr.net/npm/p5@1.11.1/lib/p5.min.js"
               " (p5 1.11.1)" in line for line in result.logs), result.logs[:5]


@pytest.mark.browser
def test_other_library_versions_are_logged_and_flagged(engines):
    head = ('<script src="https://cdnjs.cloudflare.com/ajax/libs/p5.js/1.9.0/p5.min.js"></script>'
            '<script src="https://cdn.jsdelivr.net/npm/matter-js@0.19.0/build/matter.min.js">'
            '</script>')
    result = render(engines["p5"], p5_page(head))
    assert result.ok, result.error
    assert result.flags == ["library_substituted"]
    lines = [line for line in result.logs if "library substituted" in line]
    assert len(lines) == 2
    assert "p5.js/1.9.0/p5.min.js (p5 1.9.0) -> the page's preloaded /vendor/p5.min.js (p5 1.11" \
        in lines[0]
    assert "matter-js@0.19.0/build/matter.min.js (matter-js 0.19.0) -> " in lines[1]
    assert "(matter-js 0.20.0)" in lines[1]


@pytest.mark.browser
def test_three_esm_substitution_and_two_three_instances_are_logged(engines):
    page = """<!DOCTYPE html><html><head><script type="importmap">
    {"imports": {"three": "https://unpkg.com/three@0.160.0/build/three.module.js"}}</script>
    </head><body><script type="module">
    import * as THREE from 'three';
    const renderer = new THREE.WebGLRenderer();
    renderer.setSize(128, 128);
    document.body.appendChild(renderer.domElement);
    setupRecording(renderer.domElement, 1800);
    const scene = new THREE.Scene(); scene.background = new THREE.Color(0xffffff);
    const camera = new THREE.OrthographicCamera(-64, 64, 64, -64, 0.1, 10);
    camera.position.z = 5;
    const disc = new THREE.Mesh(new THREE.CircleGeometry(10, 32),
                                new THREE.MeshBasicMaterial({ color: 0xff0000 }));
    scene.add(disc);
    let t = 0;
    function loop() { t += 1 / 60; disc.position.x = -50 + 40 * t;
      renderer.render(scene, camera); requestAnimationFrame(loop); }
    requestAnimationFrame(loop);
    </script></body></html>"""
    result = render(engines["threejs"], page)
    assert result.ok, result.error
    assert result.flags == ["library_substituted"]
    assert any("three@0.160.0/build/three.module.js (three 0.160.0) -> "
               "/vendor/npm/three-esm/build/three.module.js (three 0.187" in line
               for line in result.logs), result.logs[:5]
    twice = [line for line in result.logs if "two three.js instances" in line]
    assert len(twice) == 1 and "0.160.1 (/vendor/three.min.js, preloaded)" in twice[0]
    assert "0.187.0 (/vendor/npm/three-esm/build/three.module.js" in twice[0]


@pytest.mark.browser
def test_no_recording_call_is_flagged_where_the_engine_asks_for_it(engines):
    result = render(engines["p5"], p5_page(record=False))
    assert result.ok and result.flags == ["no_recording_call"]
    assert any("never called setupRecording" in line for line in result.logs)
    # the recording call only names the canvas: the frames are the same
    recorded = render(engines["p5"], p5_page())
    assert np.array_equal(result.frames, recorded.frames)
    # the SVG engine's instructions make the call optional
    svg = """<!DOCTYPE html><html><body><svg width="128" height="128" viewBox="0 0 128 128">
    <circle id="b" cx="10" cy="64" r="10" fill="#0000ff"/></svg><script>
    let x = 10; setInterval(() => { x += 2; document.getElementById('b').setAttribute('cx', x); },
                            1000 / 60);</script></body></html>"""
    result = render(engines["svg"], svg)
    assert result.ok and result.flags == []


@pytest.mark.browser
def test_a_canvas_of_another_size_is_flagged_and_letterboxed(engines):
    result = render(engines["p5"], p5_page(size=64).replace("createCanvas(64, 64)",
                                                             "createCanvas(128, 64)"))
    assert result.ok and result.flags == ["canvas_resized"], (result.flags, result.error)
    assert any("the recorded canvas is 128x64 px, not the clip's 128x128" in line
               for line in result.logs)
    frame = result.frames[0]
    assert np.all(frame[:32] == 255) and np.all(frame[96:] == 255)  # bars above and below
    ys, xs = np.nonzero(np.all(frame == (0, 0, 255), axis=2))
    assert 54 <= ys.min() and ys.max() <= 74  # the disc, in the middle band


@pytest.mark.browser
def test_runtime_error_keeps_the_frames_before_it(engines):
    # draw() throws from t = 1 s on (draw #61): frames at 0, 0.2, ..., 0.8 s came before it
    failing = p5_page(draw_extra="if (millis() >= 1000) { undefinedHelper(); }")
    result = render(engines["p5"], failing)
    assert result.failure is FailureClass.RUNTIME_ERROR and "undefinedHelper" in result.error
    assert result.flags == ["partial_clip"] and result.frames is None
    assert result.partial_frames.shape == (5, 128, 128, 3)
    full = render(engines["p5"], p5_page())
    assert np.array_equal(result.partial_frames, full.frames[:5])
    # an error before the first frame leaves no partial clip
    early = render(engines["p5"], p5_page(draw_extra="undefinedHelper();"))
    assert early.failure is FailureClass.RUNTIME_ERROR
    assert early.partial_frames is None and "partial_clip" not in early.flags


@pytest.mark.browser
def test_a_page_blocked_from_its_library_names_the_request(engines):
    url = "https://cdn.example.org/libs/physics-engine.min.js"
    page = (f'<!DOCTYPE html><html><head><script src="{url}"></script></head><body><script>'
            "window.addEventListener('load', function () {});</script></body></html>")
    result = render(engines["threejs"], page)
    assert result.failure is FailureClass.BLANK_OUTPUT
    assert result.error == ("the page has no canvas (or <svg>) to record; blocked request(s): "
                            f"{url} (not vendored)")
    # and when the page fails for want of it, the runtime error names it too
    page = page.replace("function () {}", "function () { PhysicsEngine.create(); }")
    result = render(engines["threejs"], page)
    assert result.failure is FailureClass.RUNTIME_ERROR
    assert "PhysicsEngine" in result.error and f"{url} (not vendored)" in result.error


@pytest.mark.browser
def test_flags_and_the_partial_clip_survive_the_render_cache(engines, tmp_path):
    cache = Cache(tmp_path)
    program = Program("html", p5_page(head=P5_TAG.replace("1.11.1", "1.9.0"), record=False,
                                      draw_extra="if (millis() >= 1000) { undefinedHelper(); }"))
    fresh = render_cached(engines["p5"], program, CONTRACT, cache)
    cached = render_cached(engines["p5"], program, CONTRACT, cache)
    assert not fresh.cached and cached.cached
    assert fresh.failure is cached.failure is FailureClass.RUNTIME_ERROR
    expect = {"partial_clip", "no_recording_call", "library_substituted"}
    assert set(fresh.flags) == set(cached.flags) == expect
    assert cached.logs == fresh.logs
    frames, _ = decode_video(cached.partial_path)
    assert frames.shape == (5, 128, 128, 3)


# ------------------------------------------------------------------------ pipeline (stand-in)

class FlaggingEngine(Engine):
    """Fails with a partial clip (a program containing "fail"), else renders a moving square;
    both with the flags of its program's first line."""

    name, language, version = "flagging", "html", "1"

    def __init__(self, cfg=None):
        super().__init__(cfg)
        self.renders = 0

    def extract(self, text):
        return Program("html", text)

    def validate(self, program):
        pass

    def render(self, program, contract):
        self.renders += 1
        frames = np.full((contract.n_frames, contract.height, contract.width, 3), 255, np.uint8)
        for k in range(contract.n_frames):
            frames[k, 8:16, 2 * k:2 * k + 8] = 0
        flags = program.source.splitlines()[0].split()
        if "fail" in program.source:
            return RenderResult(frames=None, failure=FailureClass.RUNTIME_ERROR,
                                error="Error: boom", logs=["[visphy] partial clip: 2 frames"],
                                flags=flags, partial_frames=frames[:2], isolation="test")
        return RenderResult(frames=frames, flags=flags, logs=["ok"], isolation="test")

    def program_from_spec(self, scene):
        raise NotImplementedError


def test_stand_in_flags_and_partial_clip_are_cached(tmp_path):
    cache, engine = Cache(tmp_path), FlaggingEngine()
    contract = RenderContract(fps=5, n_frames=6, width=32, height=32, timeout_s=30)
    program = Program("html", "partial_clip library_substituted\nfail")
    first = render_cached(engine, program, contract, cache)
    second = render_cached(engine, program, contract, cache)
    assert engine.renders == 1 and second.cached
    assert first.flags == second.flags == ["partial_clip", "library_substituted"]
    assert decode_video(second.partial_path)[0].shape == (2, 32, 32, 3)
    ok = render_cached(engine, Program("html", "canvas_resized\nok"), contract, cache)
    assert ok.flags == ["canvas_resized"] and ok.partial_path is None


def test_rows_carry_the_render_flags_and_the_scene_dir_the_partial_clip(tmp_path, mini_root):
    import shutil

    from conftest import with_fast_metrics
    from visphy_core.api.hookspecs import hookimpl
    from visphy_core.api.model import Model, ModelResponse
    from visphy_core.api.registry import get_plugin_manager, get_registry
    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment

    class Replies(Model):
        name = "replies"

        def generate(self, request):
            text = ("partial_clip no_recording_call\nfail" if request.attempt == 1
                    else "library_substituted\nok")
            return ModelResponse(text=text)

    class Plugin:
        @hookimpl
        def visphy_register_engines(self, register):
            register("flagging", FlaggingEngine)

        @hookimpl
        def visphy_register_models(self, register):
            register("replies", Replies)

    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)

    def run() -> tuple[dict, Path]:
        pm = get_plugin_manager()
        pm.register(Plugin(), name="flagging-test")
        get_registry.cache_clear()
        try:
            cfg = compose(list(with_fast_metrics((
                f"paths.root={home}", "tracking=none", "run.progress=false", "model=oracle",
                "engine=threejs", "model.name=replies", "engine.name=flagging",
                "dataset.limit=1"))))
            summary = run_experiment(cfg)
        finally:
            pm.unregister(name="flagging-test")
            get_registry.cache_clear()
        (row,) = [json.loads(line) for line in
                  (Path(summary["run_dir"]) / "results.jsonl").read_text().splitlines()]
        return row, Path(summary["run_dir"]) / "scenes" / row["scene_id"]

    for attempt in ("fresh", "cached"):
        row, scene_dir = run()
        assert row["render_cached"] is (attempt == "cached")
        assert row["model_success"] and row["first_failure_class"] == "runtime_error"
        # the row shows the flags of the render it reports (the repaired program's)
        assert row["flags"] == "library_substituted", (attempt, row["flags"])
        assert decode_video(scene_dir / "partial.mp4")[0].shape[0] == 2
        assert not (scene_dir / "partial.attempt2.mp4").exists()
        first_log = (scene_dir / "render.log").read_text()
        assert "flags: partial_clip, no_recording_call" in first_log
        assert "partial clip: partial.mp4" in first_log
        assert "flags: library_substituted" in (scene_dir / "render.attempt2.log").read_text()


def test_render_flag_values_are_the_documented_names():
    assert [f.value for f in RenderFlag] == ["library_substituted", "no_recording_call",
                                             "canvas_resized", "partial_clip"]


@pytest.mark.parametrize("blocked, navigations", [
    (["navigation http://127.0.0.1:9/form"], []), ([], ["http://127.0.0.1:9/away"])])
def test_a_page_that_tried_to_leave_is_a_violation_even_if_it_then_timed_out(blocked,
                                                                              navigations):
    from visphy_core.sandbox.browser import PageCapture
    from visphy_plugins.engines.browser_base import classify_capture

    contract = RenderContract(fps=5, n_frames=3, width=64, height=64, timeout_s=8)
    cap = PageCapture(blocked_requests=list(blocked), navigations=list(navigations),
                      timed_out=True)
    result = classify_capture(cap, contract)
    assert result.failure is FailureClass.SANDBOX_VIOLATION
    assert result.error.startswith("the page tried to leave: ") and "127.0.0.1:9/" in result.error
    assert "[visphy] and then no result within 8 s" in result.logs
    plain = classify_capture(PageCapture(timed_out=True), contract)
    assert plain.failure is FailureClass.TIMEOUT
