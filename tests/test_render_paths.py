"""The fast render path against the path it replaced: the same frames, byte for byte.

The fast path (the default `BrowserPool`) reads canvases back as raw pixels, several frames per
call, in pages prepared ahead with the engine's libraries loaded; the PNG path (``readback="png",
prepare_pages=False``) is the one it replaced. Both render the same programs in this test run and
their frame digests are compared: model-style programs of the corpus (three.js WebGL and 2D
canvas, p5 with matter-js, WEBGL mode and off-screen buffers, SVG screenshots), reference
programs of a mini scene, and programs written to break a careless fast path (translucent
canvases, which must fall back to PNG; a program that leaves its own framebuffer and pixel-pack
state bound; promise- and task-driven loops, which see the task boundaries between frames; an
anti-aliased, lit, translucent 3D scene). A prepared page must carry nothing between programs.
"""

from __future__ import annotations

import base64
import re
from pathlib import Path

import numpy as np
import pytest

from visphy_core.api.engine import Program, RenderContract
from visphy_core.infra.video import frame_digest

pytestmark = pytest.mark.browser

CORPUS = Path(__file__).with_name("corpus")
CONTRACT = RenderContract(fps=5, n_frames=17, width=256, height=256, timeout_s=60)
SMALL = RenderContract(fps=5, n_frames=9, width=128, height=128, timeout_s=60)


@pytest.fixture(scope="module")
def paths():
    """Engines on the fast path (the shared pool) and the same engines on the PNG path."""
    from visphy_core.sandbox.browser import BrowserPool
    from visphy_plugins.engines.browser_base import close_shared_pool
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    kinds = {"threejs": ThreeJsEngine, "p5": P5Engine, "svg": SvgEngine}
    legacy = BrowserPool(readback="png", prepare_pages=False)
    fast = {name: cls() for name, cls in kinds.items()}
    png = {name: cls() for name, cls in kinds.items()}
    for engine in png.values():
        engine.pool = legacy
    yield {"fast": fast, "png": png}
    legacy.close()
    close_shared_pool()


def page(body: str, script: str, size: int = 128) -> Program:
    return Program("html", f'<html><body style="margin:0"><canvas id="c" width="{size}" '
                           f'height="{size}"></canvas>{body}<script>{script}</script></body></html>')


def render_both(paths, engine: str, program: Program, contract: RenderContract):
    """(fast capture, fast result, png result): the page on both paths."""
    from visphy_plugins.engines.browser_base import classify_capture

    fast_engine = paths["fast"][engine]
    cap, _, _ = fast_engine.capture_page(program, contract)
    fast = classify_capture(cap, contract, fast_engine.expects_recording_call)
    png = paths["png"][engine].render(program, contract)
    return cap, fast, png


def assert_same_frames(fast, png) -> None:
    assert fast.ok and png.ok, (fast.error, png.error)
    assert [frame_digest(f) for f in fast.frames] == [frame_digest(f) for f in png.frames]


# Programs written the way models write them (tests/corpus): WebGL with CANNON, ES modules,
# a 2D canvas; p5 with matter-js, WEBGL mode, an off-screen buffer; SVG by SMIL and by script.
CORPUS_CASES = [("threejs", "01_upstream_ball_drop.html"),
                ("threejs", "10_module_importmap_jsdelivr.html"),
                ("threejs", "21_upstream_canvas_2d_fallback.html"),
                ("p5", "01_matter_global_ball_drop.html"),
                ("p5", "14_webgl_mode.html"),
                ("p5", "21_create_graphics_buffer.html"),
                ("svg", "03_smil_animate_fall.html"),
                ("svg", "08_raf_two_body_collision.html")]


@pytest.mark.parametrize("engine, name", CORPUS_CASES,
                         ids=[f"{e}-{n[:2]}" for e, n in CORPUS_CASES])
def test_corpus_programs_give_identical_frames_on_both_paths(paths, engine, name):
    program = Program("html", (CORPUS / engine / name).read_text())
    cap, fast, png = render_both(paths, engine, program, CONTRACT)
    assert_same_frames(fast, png)
    if engine != "svg":  # opaque canvases: every frame came back raw, none as PNG
        assert cap.raw_frames == CONTRACT.n_frames


@pytest.mark.parametrize("engine", ["threejs", "p5", "svg"])
def test_reference_programs_give_identical_frames_on_both_paths(paths, mini_scenes, engine):
    scene = next(s for s in mini_scenes if s.dim == "2d")
    program = paths["fast"][engine].program_from_spec(scene)
    contract = RenderContract.for_scene(scene)
    cap, fast, png = render_both(paths, engine, program, contract)
    assert_same_frames(fast, png)
    assert cap.raw_frames == (0 if engine == "svg" else contract.n_frames)


TRANSLUCENT_WEBGL = page("", """
const renderer = new THREE.WebGLRenderer({canvas: document.getElementById('c'), alpha: true,
                                          premultipliedAlpha: true});
renderer.setClearColor(0x000000, 0);
const scene = new THREE.Scene();
const camera = new THREE.OrthographicCamera(0, 128, 128, 0, -1, 1);
const ball = new THREE.Mesh(new THREE.CircleGeometry(12, 48), new THREE.MeshBasicMaterial(
  {color: 0x1877f2, transparent: true, opacity: 0.55}));
scene.add(ball);
let y = 100;
function draw() { y -= 1.3; ball.position.set(64, y, 0); renderer.render(scene, camera);
                  requestAnimationFrame(draw); }
requestAnimationFrame(draw);
setupRecording(renderer.domElement, 1800);
""")

TRANSLUCENT_2D = page("", """
const ctx = document.getElementById('c').getContext('2d');
let x = 0;
function draw() {
  ctx.clearRect(0, 0, 128, 128);
  ctx.fillStyle = 'rgba(243, 79, 70, 0.4)';
  ctx.beginPath(); ctx.arc(20 + x, 64, 15, 0, 7); ctx.fill();
  x += 1; requestAnimationFrame(draw);
}
requestAnimationFrame(draw);
setupRecording(document.getElementById('c'), 1800);
""")


@pytest.mark.parametrize("program", [TRANSLUCENT_WEBGL, TRANSLUCENT_2D], ids=["webgl", "2d"])
def test_translucent_canvases_fall_back_to_png_with_the_same_frames(paths, program):
    cap, fast, png = render_both(paths, "threejs", program, SMALL)
    assert_same_frames(fast, png)
    assert cap.raw_frames == 0  # not one frame read raw: the PNG holds the unpremultiplied pixels


# Leaves its own framebuffer bound and odd pixel-pack settings between ticks, and checks at each
# tick that they are still what it left: a readback that forgot to restore them shows as red.
GL_STATE_PROBE = page("", """
const c = document.getElementById('c');
const gl = c.getContext('webgl2', {antialias: false});
const fbo = gl.createFramebuffer();
const tex = gl.createTexture();
gl.bindTexture(gl.TEXTURE_2D, tex);
gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, 4, 4, 0, gl.RGBA, gl.UNSIGNED_BYTE, null);
gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
const pbo = gl.createBuffer();
gl.bindBuffer(gl.PIXEL_PACK_BUFFER, pbo);
gl.bufferData(gl.PIXEL_PACK_BUFFER, 64, gl.STREAM_READ);
gl.pixelStorei(gl.PACK_ALIGNMENT, 1); gl.pixelStorei(gl.PACK_ROW_LENGTH, 3);
let broken = 0, tick = 0;
function draw() {
  if (gl.getParameter(gl.FRAMEBUFFER_BINDING) !== fbo ||
      gl.getParameter(gl.READ_FRAMEBUFFER_BINDING) !== fbo ||
      gl.getParameter(gl.PIXEL_PACK_BUFFER_BINDING) !== pbo ||
      gl.getParameter(gl.PACK_ALIGNMENT) !== 1 || gl.getParameter(gl.PACK_ROW_LENGTH) !== 3 ||
      gl.getError() !== gl.NO_ERROR) broken += 1;
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.clearColor(broken ? 1 : 0.1, broken ? 0 : 0.6, (tick % 60) / 60, 1);
  gl.clear(gl.COLOR_BUFFER_BIT);
  gl.enable(gl.SCISSOR_TEST); gl.scissor(tick % 120, 40, 8, 8);
  gl.clearColor(0, 0, 0, 1); gl.clear(gl.COLOR_BUFFER_BIT); gl.disable(gl.SCISSOR_TEST);
  gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
  gl.pixelStorei(gl.PACK_ALIGNMENT, 1); gl.pixelStorei(gl.PACK_ROW_LENGTH, 3);
  tick += 1;
  requestAnimationFrame(draw);
}
requestAnimationFrame(draw);
setupRecording(c, 1800);
""")


def test_readback_leaves_the_programs_gl_state_as_it_was(paths):
    cap, fast, png = render_both(paths, "threejs", GL_STATE_PROBE, SMALL)
    assert_same_frames(fast, png)
    assert cap.raw_frames == SMALL.n_frames
    top_left = fast.frames[:, 0, 0]
    assert (top_left[:, 0] < 60).all() and (top_left[:, 1] > 120).all()  # never red
    again, _, _ = paths["fast"]["threejs"].capture_page(GL_STATE_PROBE, SMALL)
    assert [frame_digest(f) for f in again.frames] == [frame_digest(f) for f in fast.frames]


# A loop driven by promises and a task: what it draws depends on how many microtasks and
# MessageChannel tasks ran between two frames (reading several frames per call would change it).
TASK_DRIVEN = page("", """
const ctx = document.getElementById('c').getContext('2d');
let micro = 0, tasks = 0;
const ch = new MessageChannel();
ch.port1.onmessage = () => { tasks += 1; };
async function chain(n) { for (let i = 0; i < n; i++) { await null; micro += 1; } }
function draw(t) {
  chain(3);
  ch.port2.postMessage(0);
  ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, 128, 128);
  ctx.fillStyle = '#f34f46'; ctx.fillRect(micro % 128, 10, 6, 6);
  ctx.fillStyle = '#1877f2'; ctx.fillRect(tasks % 128, 30, 6, 6);
  ctx.fillStyle = '#000'; ctx.fillRect(Math.round(t / 20) % 128, 50, 6, 6);
  requestAnimationFrame(draw);
}
requestAnimationFrame(draw);
setupRecording(document.getElementById('c'), 1800);
""")


def test_task_and_microtask_driven_loops_give_identical_frames(paths):
    cap, fast, png = render_both(paths, "threejs", TASK_DRIVEN, SMALL)
    assert_same_frames(fast, png)
    assert cap.raw_frames == SMALL.n_frames
    blue_x = [int(np.nonzero((f[30, :, 2] > 200) & (f[30, :, 0] < 60))[0].min())
              for f in fast.frames]
    assert blue_x[-1] > blue_x[0]  # the tasks between frames did run


# Anti-aliased (multisampled) WebGL, lights, a translucent container, a perspective camera:
# the look of the 3D scenes.
LIT_3D = page("", """
const renderer = new THREE.WebGLRenderer({canvas: document.getElementById('c'), antialias: true});
renderer.setClearColor(0xffffff, 1);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(45, 1, 0.1, 100);
camera.position.set(7, 6.2, 8.2); camera.lookAt(0, 1.2, 0);
scene.add(new THREE.HemisphereLight(0xffffff, 0x444444, 1.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.5); sun.position.set(3, 10, 4); scene.add(sun);
const floor = new THREE.Mesh(new THREE.PlaneGeometry(18, 18),
                             new THREE.MeshStandardMaterial({color: 0x979797}));
floor.rotation.x = -Math.PI / 2; scene.add(floor);
const ball = new THREE.Mesh(new THREE.SphereGeometry(0.6, 32, 16),
                            new THREE.MeshStandardMaterial({color: 0xf34f46}));
scene.add(ball);
const jar = new THREE.Mesh(new THREE.BoxGeometry(2, 1.5, 2), new THREE.MeshStandardMaterial(
  {color: 0x6bcebb, transparent: true, opacity: 0.45}));
jar.position.set(-1.5, 0.75, 0); scene.add(jar);
const world = new CANNON.World(); world.gravity.set(0, -9.82, 0);
const body = new CANNON.Body({mass: 1, shape: new CANNON.Sphere(0.6)});
body.position.set(1.5, 5, 0); body.velocity.set(-1, 0, 0.5); world.addBody(body);
const ground = new CANNON.Body({mass: 0, shape: new CANNON.Plane()});
ground.quaternion.setFromAxisAngle(new CANNON.Vec3(1, 0, 0), -Math.PI / 2); world.addBody(ground);
function draw() { world.step(1 / 60); ball.position.copy(body.position);
                  renderer.render(scene, camera); requestAnimationFrame(draw); }
requestAnimationFrame(draw);
setupRecording(renderer.domElement, 1800);
""")


def test_antialiased_lit_3d_scene_gives_identical_frames(paths):
    cap, fast, png = render_both(paths, "threejs", LIT_3D, SMALL)
    assert_same_frames(fast, png)
    assert cap.raw_frames == SMALL.n_frames
    assert len({frame_digest(f) for f in fast.frames}) > 1


# ----------------------------------------------------------------------- prepared pages

# Leaves state behind in every place a page can (storage, cookies, window.name, history, a
# global); the probe then reports what it finds at the very start of its own document.
LEAVER = page("", """
localStorage.setItem('left', '1'); sessionStorage.setItem('left', '1');
document.cookie = 'left=1; path=/'; window.name = 'left'; window.leftover = 1;
history.pushState({}, '', '#left');
const ctx = document.getElementById('c').getContext('2d');
ctx.fillStyle = '#f34f46'; ctx.fillRect(0, 0, 128, 128);
""", size=256)

PROBE = Program("html", """<html><head><script>
console.log('probe ' + JSON.stringify([typeof THREE, typeof CANNON, typeof window.leftover,
  localStorage.length, sessionStorage.length, document.cookie, window.name, history.length,
  location.hash]));
</script></head><body style="margin:0"><svg width="256" height="256">
<rect x="0" y="0" width="256" height="256" fill="#6bcebb"/>
<circle id="b" cx="40" cy="40" r="20" fill="#1877f2"/></svg>
<script>
let x = 40;
setInterval(() => { x += 5; document.getElementById('b').setAttribute('cx', x); }, 100);
</script>
</body></html>""")


def probe_line(result) -> str:
    return next(line for line in result.logs if "probe [" in line)


def test_a_prepared_page_carries_nothing_from_earlier_programs(paths):
    """The page a program gets was prepared (a blank document ran its init: the clock, three.js
    and cannon) and still starts empty: no storage, cookie, window name, global or history entry
    of the program before, the libraries as the init left them, the same as a page made on
    demand."""
    fast = paths["fast"]
    assert fast["threejs"].render(LEAVER, CONTRACT).ok
    cap, _, _ = fast["threejs"].capture_page(PROBE, CONTRACT)
    assert cap.page_prepared
    line = next(line for line in cap.console if "probe [" in line)
    assert line.endswith('probe ["object","object","undefined",0,0,"","",2,""]'), line
    assert probe_line(paths["png"]["threejs"].render(PROBE, CONTRACT)) == line
    # an engine that preloads nothing gets a page without libraries
    cap, _, _ = fast["svg"].capture_page(PROBE, CONTRACT)
    line = next(line for line in cap.console if "probe [" in line)
    assert line.endswith('probe ["undefined","undefined","undefined",0,0,"","",2,""]'), line


def test_frames_spread_over_several_page_calls_are_the_same_frames(paths, monkeypatch):
    """A page hands back as many frames per call as fit its budget: with no budget each call
    brings one frame, with a payload limit of one frame too, and the clip is the same."""
    import visphy_core.sandbox.page as page_steps

    engine = paths["fast"]["threejs"]
    whole, _, _ = engine.capture_page(TASK_DRIVEN, SMALL)
    assert whole.frame_calls < SMALL.n_frames
    for budget_ms, max_chars in ((0, page_steps.SPAN_MAX_CHARS), (10_000, 1)):
        monkeypatch.setattr(page_steps, "SPAN_BUDGET_MS", budget_ms)
        monkeypatch.setattr(page_steps, "SPAN_MAX_CHARS", max_chars)
        split, _, _ = engine.capture_page(TASK_DRIVEN, SMALL)
        assert split.frame_calls == SMALL.n_frames
        assert [frame_digest(f) for f in split.frames] == \
            [frame_digest(f) for f in whole.frames]


def test_a_page_starts_no_browser_ui_renderer(paths):
    """Each context opens a hidden browser window; Chromium must not give it a WebUI renderer
    of its own (the omnibox pop-up's, ~400 modules loaded per page)."""
    import os

    from visphy_core.sandbox.chromium import descendants

    import time

    def renderers() -> list[bytes]:
        out = []
        for pid in descendants(os.getpid()):
            try:  # (Chromium rewrites its title: its arguments become one string)
                command = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
            except OSError:
                continue
            if b"--type=renderer" in command:
                out.append(command)
        return out

    assert paths["fast"]["threejs"].render(TASK_DRIVEN, SMALL).ok
    deadline = time.monotonic() + 20
    while not renderers() and time.monotonic() < deadline:
        time.sleep(0.1)  # the next page is being prepared (its window opens with it)
    time.sleep(1.5)
    assert renderers()
    assert not [c for c in renderers() if b"--top-chrome-webui" in c]


def test_every_page_records_where_its_time_went(paths):
    cap, _, _ = paths["fast"]["threejs"].capture_page(TASK_DRIVEN, SMALL)
    assert {"page", "load", "ready", "frames", "decode", "state"} <= set(cap.timings)
    assert 0 < sum(cap.timings.values()) <= cap.wall_s + 1e-6


# ------------------------------------------------------------------------------ readback codec

def _runs(counts, values) -> str:
    words = np.empty(2 * len(counts), dtype="<u4")
    words[0::2], words[1::2] = counts, values
    return base64.b64encode(words.tobytes()).decode()


def test_run_length_payload_decodes_to_rows_in_the_right_order():
    from visphy_core.sandbox.readback import raw_to_rgb

    red, blue = 0xFF0000FF, 0xFFFF0000  # little-endian RGBA: (255,0,0,255), (0,0,255,255)
    payload = {"runs": _runs([3, 3], [red, blue]), "width": 3, "height": 2}
    top_down = raw_to_rgb(payload)
    assert top_down[0].tolist() == [[255, 0, 0]] * 3 and top_down[1].tolist() == [[0, 0, 255]] * 3
    flipped = raw_to_rgb({**payload, "flipY": True})
    assert np.array_equal(flipped, top_down[::-1])
    raw = np.arange(2 * 3 * 4, dtype=np.uint8)
    plain = raw_to_rgb({"raw": base64.b64encode(raw.tobytes()).decode(), "width": 3,
                        "height": 2})
    assert np.array_equal(plain, raw.reshape(2, 3, 4)[..., :3])


@pytest.mark.parametrize("payload, message", [
    ({"runs": _runs([5], [0xFFFFFFFF]), "width": 3, "height": 2}, "cover 5 pixels"),
    ({"raw": base64.b64encode(b"\0" * 10).decode(), "width": 3, "height": 2}, "10 bytes"),
])
def test_a_payload_that_is_not_a_whole_frame_is_refused(payload, message):
    from visphy_core.sandbox.readback import ReadbackError, raw_to_rgb

    with pytest.raises(ReadbackError, match=re.escape(message)):
        raw_to_rgb(payload)
