"""The browser engines threejs, p5 and svg on a corpus of programs written the way models write
them, their failure classes, their reference programs on the mini scenes, the 2D constraint
helper, and the pool's recovery from a renderer crash.

One engine of each kind per module (they share one Chromium pool), small clips (256², 17 frames
at 5 fps) for the corpus.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from visphy_core.api.engine import FailureClass, Program, RenderContract, classify_frames
from visphy_core.infra.video import frame_digest

pytestmark = pytest.mark.browser

CORPUS = Path(__file__).with_name("corpus")
ENGINE_NAMES = ("threejs", "p5", "svg")
CONTRACT = RenderContract(fps=5, n_frames=17, width=256, height=256, timeout_s=30)
FAST_FAIL = RenderContract(fps=5, n_frames=17, width=256, height=256, timeout_s=4)


@pytest.fixture(scope="module")
def engines():
    from visphy_plugins.engines.browser_base import close_shared_pool
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    made = {"threejs": ThreeJsEngine(), "p5": P5Engine(), "svg": SvgEngine()}
    yield made
    close_shared_pool()


def digests(frames: np.ndarray) -> list[str]:
    return [frame_digest(f) for f in frames]


# --------------------------------------------------------------------------------------- corpus

def corpus() -> list[tuple[str, Path]]:
    return [(name, path) for name in ENGINE_NAMES
            for path in sorted((CORPUS / name).glob("*.html"))]


def test_corpus_has_at_least_twenty_programs_per_engine():
    counts = {name: len(list((CORPUS / name).glob("*.html"))) for name in ENGINE_NAMES}
    assert all(n >= 20 for n in counts.values()), counts
    for name in ENGINE_NAMES:
        for path in (CORPUS / name).glob("*.html"):
            assert re.fullmatch(r"\d\d_[a-z0-9_]+\.html", path.name), path.name


#: Every third program of each engine is rendered twice (the determinism check); the clock that
#: makes them repeatable is the same for all, and a render is ≈ 1 s of the suite's time.
TWICE = {(e, p.name) for e in ENGINE_NAMES
         for i, p in enumerate(sorted((CORPUS / e).glob("*.html"))) if i % 3 == 0}


@pytest.mark.parametrize("engine_name, path", corpus(),
                         ids=[f"{e}/{p.stem}" for e, p in corpus()])
def test_corpus_program_renders_deterministically(engines, engine_name, path):
    engine = engines[engine_name]
    program = engine.extract(f"Analysis: see the code.\n\n```html\n{path.read_text()}\n```\n")
    engine.validate(program)
    first = engine.render(program, CONTRACT)
    assert first.ok, (first.failure, first.error, first.logs[:5])
    assert first.frames.shape == (17, 256, 256, 3)
    assert classify_frames(first.frames) is None, "the clip does not move"
    # every library URL was served from the vendored copies: nothing left the page
    assert not first.blocked_requests, first.blocked_requests
    if (engine_name, path.name) not in TWICE:
        return
    second = engine.render(program, CONTRACT)
    assert second.ok, (second.failure, second.error)
    assert digests(first.frames) == digests(second.frames)


# ------------------------------------------------------------------------------- failure classes

P5_FAILURES = [
    ("function setup() { createCanvas(128, 128); }\nfunction draw( { background(0); }",
     FailureClass.SYNTAX_ERROR),
    ("function setup() { createCanvas(128, 128); }\n"
     "function draw() { if (millis() > 500) throw new Error('boom at 0.5 s');\n"
     "  background(255); rect(frameCount, 10, 10, 10); }", FailureClass.RUNTIME_ERROR),
    ("function setup() { createCanvas(128, 128); }\n"
     "function draw() { background(255); rect(frameCount, 0, 5, 5);\n"
     "  if (frameCount > 20) for (;;) {} }",
     FailureClass.TIMEOUT),
    ("function setup() { noCanvas(); }\nfunction draw() { }", FailureClass.BLANK_OUTPUT),
    ("function setup() { createCanvas(128, 128); }\nfunction draw() { background(255); }",
     FailureClass.BLANK_OUTPUT),
    ("function setup() { createCanvas(128, 128);\n"
     "  fetch('https://example.com/x?k=1').catch(() => {}); }\n"
     "function draw() { background(255); rect(frameCount, 0, 5, 5); }",
     FailureClass.SANDBOX_VIOLATION),
]

SVG_FAILURES = [
    ('<svg width="128" height="128"><circle id="c" r="5" cx="5" cy="5"/></svg>',
     "setInterval(() => { c.setAttribute('cx', 10 }, 20);", FailureClass.SYNTAX_ERROR),
    ('<svg width="128" height="128"><circle id="c" r="5" cx="5" cy="5"/></svg>',
     "let t0 = performance.now(); setInterval(() => { const t = performance.now() - t0;"
     " if (t > 500) throw new Error('boom at 0.5 s'); c.setAttribute('cx', t / 10); }, 20);",
     FailureClass.RUNTIME_ERROR),
    ('<svg width="128" height="128"><circle id="c" r="5" cx="5" cy="5"/></svg>',
     "requestAnimationFrame(function f(t) { if (t > 300) for (;;) {} c.setAttribute('cx', t / 10);"
     " requestAnimationFrame(f); });", FailureClass.TIMEOUT),
    ("<div id='c'></div>", "console.log('nothing to show');", FailureClass.BLANK_OUTPUT),
    ('<svg width="128" height="128"><rect width="128" height="128" fill="#fff"/></svg>',
     "setInterval(() => {}, 20);", FailureClass.BLANK_OUTPUT),
    ('<svg width="128" height="128"><circle id="c" r="5" cx="5" cy="5"/></svg>',
     "fetch('https://example.com/x?k=1').catch(() => {});"
     "setInterval(() => c.setAttribute('cx', performance.now() / 10), 20);",
     FailureClass.SANDBOX_VIOLATION),
]

GOOD = {
    "p5": Program("html", "<html><body><script>function setup(){createCanvas(64,64);}"
                          "function draw(){background(255);fill(0);rect(frameCount%60,5,4,4);}"
                          "</script></body></html>"),
    "svg": Program("html", '<html><body><svg width="64" height="64"><circle id="c" r="4" cy="8"/>'
                           "</svg><script>setInterval(() => c.setAttribute('cx', "
                           "performance.now() / 50), 20);</script></body></html>"),
}


@pytest.mark.parametrize("source, failure", P5_FAILURES,
                         ids=[f.value for _, f in P5_FAILURES])
def test_p5_failure_classes(engines, source, failure):
    engine = engines["p5"]
    result = engine.render(Program("html", f"<html><body><script>{source}</script></body></html>"),
                           FAST_FAIL)
    assert result.failure is failure, (result.error, result.logs[:5])
    assert result.frames is None
    assert engine.render(GOOD["p5"], CONTRACT).ok  # the run goes on


@pytest.mark.parametrize("markup, script, failure", SVG_FAILURES,
                         ids=[f.value for _, _, f in SVG_FAILURES])
def test_svg_failure_classes(engines, markup, script, failure):
    engine = engines["svg"]
    page = f"<html><body>{markup}<script>const c = document.getElementById('c');\n{script}" \
           "</script></body></html>"
    result = engine.render(Program("html", page), FAST_FAIL)
    assert result.failure is failure, (result.error, result.logs[:5])
    assert result.frames is None
    assert engine.render(GOOD["svg"], CONTRACT).ok


# --------------------------------------------------------------------------- virtual time in p5/svg

def _dark_box(frame: np.ndarray) -> tuple[int, int]:
    """Left column and height of the dark pixels."""
    ys, xs = np.nonzero(frame.max(axis=-1) < 100)
    return int(xs.min()), int(ys.max() - ys.min() + 1)


def test_p5_draw_millis_deltatime_and_framecount_follow_virtual_time(engines):
    # x = millis()/20, height = deltaTime (16.67 ms at 60 Hz), width = frameCount
    program = Program("html", """<html><body><script>
function setup() { createCanvas(256, 64); pixelDensity(1); noSmooth(); noStroke(); }
function draw() {
  background(255); fill(0);
  rect(Math.round(millis() / 20), 0, 1, Math.round(deltaTime));
  fill(255, 0, 0); rect(0, 40, frameCount, 4);
}
</script></body></html>""")
    contract = RenderContract(fps=5, n_frames=6, width=256, height=64, timeout_s=20)
    result = engines["p5"].render(program, contract)
    assert result.ok, (result.error, result.logs[:5])
    boxes = [_dark_box(f) for f in result.frames]
    assert [x for x, _ in boxes] == [0, 10, 20, 30, 40, 50]  # frame k at t = 200 k ms
    assert {h for _, h in boxes} == {17}                     # deltaTime = 1000/60 ms
    counts = [int(np.count_nonzero((f[41, :, 0] > 200) & (f[41, :, 1] < 80)))
              for f in result.frames]
    assert counts == [1 + 12 * k for k in range(6)]          # draw() #1 at t = 0, then one per tick


def test_svg_smil_and_timers_follow_virtual_time(engines):
    program = Program("html", """<html><body>
<svg width="256" height="64">
  <rect y="0" width="6" height="20" fill="#000"><animate attributeName="x" from="0" to="160"
        dur="3.2s" fill="freeze"/></rect>
  <rect id="t" y="30" x="0" width="6" height="20" fill="#000"/>
</svg>
<script>let n = 0; setInterval(() => { n += 1; document.getElementById('t').setAttribute('x', n); },
100);</script></body></html>""")
    contract = RenderContract(fps=5, n_frames=6, width=256, height=64, timeout_s=20)
    result = engines["svg"].render(program, contract)
    assert result.ok, (result.error, result.logs[:5])
    smil = [int(np.nonzero(f[10].max(axis=-1) < 100)[0].min()) for f in result.frames]
    timer = [int(np.nonzero(f[40].max(axis=-1) < 100)[0].min()) for f in result.frames]
    assert smil == [0, 10, 20, 30, 40, 50]   # SMIL seeked to t = 200 k ms
    assert timer == [0, 2, 4, 6, 8, 10]      # one setInterval tick per 100 ms


# ---------------------------------------------------------------------- reference programs (oracle)

def _centres(frames: np.ndarray, spec: dict, tol: float = 15.0) -> list[list]:
    """Centre (x, y) per frame of every body whose colour no other body has (None if unseen):
    the mean of the pixels within `tol` of that colour (exact palette, tolerant to the video)."""
    colours = [tuple(b["color_rgb"]) for b in spec["bodies"]]
    out = []
    for frame in frames.astype(np.int32):
        row = []
        for colour in colours:
            if colours.count(colour) != 1:
                row.append(None)
                continue
            mask = np.sum((frame - np.array(colour)) ** 2, axis=-1) < tol ** 2
            ys, xs = np.nonzero(mask)
            row.append((xs.mean(), ys.mean()) if len(xs) else None)
        out.append(row)
    return out


def centre_error(frames: np.ndarray, truth: np.ndarray, spec: dict) -> float:
    """Mean distance (px) between object centres measured in two clips."""
    errs = [np.hypot(a[0] - b[0], a[1] - b[1])
            for ra, rb in zip(_centres(frames, spec), _centres(truth, spec))
            for a, b in zip(ra, rb) if a is not None and b is not None]
    assert errs, "no body could be measured"
    return float(np.mean(errs))


# p5's reference program writes the ground truth's pixels exactly; SVG draws real shapes with
# crispEdges, whose edge rule is Chromium's (the conformance floor is 38 dB)
@pytest.mark.parametrize("engine_name, max_error, min_psnr",
                         [("p5", 0.5, 60.0), ("svg", 2.0, 38.0)])
def test_reference_programs_track_the_ground_truth(engines, mini_scenes, engine_name, max_error,
                                                   min_psnr):
    from visphy_plugins.metrics.pixel import psnr_frame

    engine = engines[engine_name]
    for scene in mini_scenes:
        assert scene.dim == "2d"
        result = engine.render(engine.program_from_spec(scene), RenderContract.for_scene(scene))
        assert result.ok, (scene.scene_id, result.error, result.logs[:5])
        assert result.flags == [], (scene.scene_id, result.flags)  # nothing done to the page
        truth = scene.reference_frames()
        assert result.frames.shape == truth.shape
        error = centre_error(result.frames, truth, scene.spec)
        psnr = float(np.mean([psnr_frame(a, b) for a, b in zip(result.frames, truth)]))
        assert error <= max_error, f"{scene.scene_id}: mean centre error {error:.2f} px"
        assert psnr >= min_psnr, f"{scene.scene_id}: PSNR {psnr:.1f} dB"


@pytest.mark.parametrize("engine_name", ["p5", "svg"])
def test_2d_engines_have_no_3d_reference_program(engines, engine_name):
    scene = SimpleNamespace(scene_id="01_tmpl_00", dim="3d", spec={}, trajectory={})
    with pytest.raises(NotImplementedError, match="2D only"):
        engines[engine_name].program_from_spec(scene)
    assert engines[engine_name].instructions("2d")
    assert not engines[engine_name].supports_3d


# ------------------------------------------------------------------------------ 2D constraint

Z_PROBE_UMD = """<html><body><canvas id="c" width="128" height="128"></canvas><script>
const ctx = document.getElementById('c').getContext('2d');
const world = new CANNON.World(); world.gravity.set(0, -50, 0);
const body = new CANNON.Body({ mass: 1, shape: new CANNON.Sphere(1) });
body.position.set(10, 100, 0); body.velocity.set(40, 0, 60); body.angularVelocity.set(2, 3, 1);
world.addBody(body);
function loop() {
  world.step(1 / 60);
  const q = body.quaternion, tilt = Math.hypot(q.x, q.y);
  ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, 128, 128);
  ctx.fillStyle = '#000'; ctx.fillRect(Math.round(body.position.x), 0, 3, 3);
  ctx.fillRect(Math.min(120, Math.round(Math.abs(body.position.z))), 50, 3, 3);
  ctx.fillRect(Math.min(120, Math.round(tilt * 100)), 100, 3, 3);
  requestAnimationFrame(loop);
}
requestAnimationFrame(loop);
</script></body></html>"""

Z_PROBE_ESM = Z_PROBE_UMD.replace(
    "<script>", "<script type=\"module\">import * as CANNON from "
                "'https://cdn.jsdelivr.net/npm/cannon-es@0.20.0/dist/cannon-es.js';\n", 1)


def _probe(frame: np.ndarray, row: int) -> int:
    return int(np.nonzero(frame[row + 1].max(axis=-1) < 100)[0].min())


@pytest.mark.parametrize("source", [Z_PROBE_UMD, Z_PROBE_ESM], ids=["cannon-0.6.2", "cannon-es"])
def test_2d_constraint_keeps_bodies_in_the_plane(engines, source):
    engine = engines["threejs"]
    contract = RenderContract(fps=5, n_frames=6, width=128, height=128, timeout_s=20)
    flat = engine.render(Program("html", source), contract)
    assert flat.ok, (flat.error, flat.logs[:5])
    assert [_probe(f, 0) for f in flat.frames][-1] > 40          # it moves in x
    assert {_probe(f, 50) for f in flat.frames} == {0}            # z stays 0
    assert {_probe(f, 100) for f in flat.frames} == {0}           # no tilt out of the plane
    free = engine.render(Program("html", source),
                         RenderContract(**{**contract.__dict__, "dim": "3d"}))
    assert free.ok, free.error
    assert _probe(free.frames[-1], 50) > 40                       # 3D: no clamping


# --------------------------------------------------------------------------- canonicalisation

def test_library_urls_map_to_vendored_copies():
    from visphy_plugins.engines.browser_base import THREE_ESM, vendored_url

    assert vendored_url("https://cdn.jsdelivr.net/npm/three@0.160.0/build/three.module.js") \
        == THREE_ESM
    assert vendored_url("https://unpkg.com/three@0.150.1/build/three.min.js") \
        == "/vendor/three.min.js"
    assert vendored_url("https://esm.sh/three@0.160.0") == THREE_ESM
    assert vendored_url("https://unpkg.com/three@0.160.0/examples/jsm/controls/OrbitControls.js") \
        == "/vendor/npm/three-esm/examples/jsm/controls/OrbitControls.js"
    assert vendored_url("https://cdn.jsdelivr.net/npm/cannon-es@0.20.0/dist/cannon-es.js") \
        == "/vendor/cannon-es.js"
    assert vendored_url("https://cdnjs.cloudflare.com/ajax/libs/cannon.js/0.6.2/cannon.min.js") \
        == "/vendor/cannon.min.js"
    assert vendored_url("https://cdnjs.cloudflare.com/ajax/libs/p5.js/1.9.0/p5.min.js") \
        == "/vendor/p5.min.js"
    assert vendored_url("https://cdn.jsdelivr.net/npm/matter-js@0.19.0/build/matter.min.js") \
        == "/vendor/matter.min.js"
    assert vendored_url("https://cdn.jsdelivr.net/npm/lodash@4/lodash.min.js") is None
    assert vendored_url("https://example.com/three.min.js") is None
    assert vendored_url("js/three.min.js", allow_local=True) == "/vendor/three.min.js"


def test_canonicalise_merges_import_maps_and_injects_the_constraint(engines):
    import json

    source = """<html><head><script type="importmap">{"imports": {
      "three": "https://unpkg.com/three@0.160.0/build/three.module.js",
      "gsap": "https://cdn.example.org/gsap.js"}}</script></head><body>
    <script type="module">import * as THREE from 'three';</script></body></html>"""
    html = engines["threejs"].canonicalise(source, "2d")
    maps = re.findall(r'<script type="importmap">(.*?)</script>', html, re.S)
    assert len(maps) == 1
    imports = json.loads(maps[0])["imports"]
    assert imports["three"].startswith("/vendor/")
    assert imports["gsap"] == "https://cdn.example.org/gsap.js"
    assert "__visphyConstrain2D" in html
    assert "__visphyConstrain2D" not in engines["threejs"].canonicalise(source, "3d")


# ------------------------------------------------------------------------------ pool robustness

def test_renderer_crash_is_infra_error_and_the_pool_recovers(engines):
    from visphy_plugins.engines.browser_base import classify_capture, shared_pool, tick_ms_for

    contract = RenderContract(fps=5, n_frames=6, width=64, height=64, timeout_s=20)
    for name, capture in (("p5", "canvas"), ("svg", "screenshot")):
        engine = engines[name]
        cap = shared_pool().render_page(
            engine.canonicalise(GOOD[name].source), engine.assets, contract.frame_times_ms(),
            width=64, height=64, timeout_s=20, tick_ms=tick_ms_for(5), capture=capture,
            inject_fault="crash")
        result = classify_capture(cap, contract)
        assert result.failure is FailureClass.INFRA_ERROR, (result.error, result.logs[:5])
        assert len(cap.frames) == 1  # frame 0 came back, then the renderer crashed
        assert engines["p5"].render(GOOD["p5"], CONTRACT).ok
        assert engines["svg"].render(GOOD["svg"], CONTRACT).ok
