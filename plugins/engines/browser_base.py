"""What the browser engines (threejs, p5, svg) share: canonicalisation, rendering, classification.

The trusted template puts the pinned libraries and an import map in front of the program, and
points the program's own references to those libraries (CDN ``<script>`` tags, import maps, ES
module URLs) at the vendored copies: a preloaded library's tag is removed, any other known
library's URL is rewritten to ``/vendor/...`` (the page could not load a CDN anyway). For 2D scenes
it also injects the 2D constraint helper (``templates/constraint2d.js``) that keeps cannon bodies
in the x-y plane. The sandbox's virtual clock drives every frame.

What the engine did to a page is recorded, not hidden (`RenderResult.flags` and the render log):

* ``library_substituted``: a library URL asking for an explicit version was served from a
  vendored copy of another version (major.minor differs; a patch release counts as the same
  version). The log has one line per rewritten URL: requested URL and version → served file and
  version; URLs without a version are logged as served, not flagged. When three.js reports two
  instances in one page (its "Multiple instances of Three.js" warning: e.g. the preloaded r160
  global next to the r187 ES module) the log says which builds the page references.
* ``no_recording_call`` (engines whose instructions ask for ``setupRecording(canvas,
  durationMs)``: threejs, p5): the page never called it. Capture does not depend on it (the
  clock is virtual and the largest canvas is read when nothing was named), so the clip is still
  scored; a trusted probe before the program notes the call in the page log.
* ``canvas_resized``: the captured canvas is not the clip size, so every frame was scaled to
  fit (uniformly, centred, white bars).
* ``partial_clip``: a runtime error at virtual time t after frames were captured: the frames
  captured before t are `RenderResult.partial_frames`; the class stays ``runtime_error``.

A page blocked from a library (a URL that is not vendored) names the blocked request(s) in its
failure detail.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import re
from collections import ChainMap
from functools import cached_property
from pathlib import Path

import numpy as np

from visphy_core.api.engine import (
    Engine,
    FailureClass,
    Program,
    ProgramRejected,
    RenderContract,
    RenderFlag,
    RenderResult,
    classify_frames,
)
from visphy_core.api.extract import extract_code, extract_spec
from visphy_core.api.sandbox import BrowserPool, PageCapture
from visphy_core.api.spec import fill, replay_payload
from visphy_plugins.engines.assets import BROWSER_ASSETS
from visphy_plugins.engines.library_urls import (  # noqa: F401 - re-exported
    CDN_HOSTS,
    IMPORT_MAP,
    THREE_ESM,
    Substitution,
    _merge_import_maps,
    _SCRIPT_SRC_TAG,
    _substitution,
    _URL_LITERAL,
    requested_version,
    same_version,
    served_version,
    vendored_url,
)

TEMPLATES = Path(__file__).with_name("templates")

#: ``import ... from 'cannon-es'`` gets this wrapper: the real module (still reachable at
#: /vendor/npm/cannon-es/dist/cannon-es.js) with World.step patched by the 2D constraint helper
#: when the page has it (2D scenes).
CANNON_ES_REAL = "/vendor/npm/cannon-es/dist/cannon-es.js"
CANNON_ES_WRAPPER = f"""// visphy: cannon-es 0.20, with the 2D constraint helper in 2D scenes
export * from '{CANNON_ES_REAL}';
import {{ World }} from '{CANNON_ES_REAL}';
if (typeof window !== 'undefined' && window.__visphyConstrain2D) window.__visphyConstrain2D(World);
"""

#: Attempts a program makes on its own (script-driven), as opposed to passive resources (an
#: ``<img>`` or a ``<script>`` from another host is refused and logged, not a violation): any of
#: these, or any attempt on a ``file:`` URL, is a sandbox violation.
ACTIVE_REQUESTS = ("fetch", "xhr", "websocket", "eventsource", "ping", "webrtc", "navigation",
                   "popup", "file")

#: What three.js logs when a second copy of it initialises in the same page.
THREE_TWICE = "Multiple instances of Three.js being imported"
_IMPORTS_THREE = re.compile(r"""(?:\bfrom\s*|\bimport\s*\(?\s*)["']three["']""")

#: Trusted probe for engines that expect ``setupRecording(canvas, durationMs)``: it runs before
#: the program and notes the program's first call in the page log (``[visphy] setupRecording(``),
#: keeping the log's last slots (the page log holds 500 lines) free for that note.
RECORDING_PROBE = """<script>
(function () {
  var info = console.info, lines = 0, noted = false;
  ['log', 'info', 'warn', 'error'].forEach(function (level) {
    var real = console[level];
    console[level] = function () { if (lines++ < 490) return real.apply(console, arguments); };
  });
  function describe(x) {
    for (var i = 0; i < 3 && x && !(x instanceof Element); i++) {
      x = x.elt || x.domElement || x.canvas || null;
    }
    if (x instanceof HTMLCanvasElement) return '<canvas ' + x.width + 'x' + x.height + '>';
    return x instanceof Element ? '<' + x.tagName.toLowerCase() + '>' : String(typeof x);
  }
  function note(target, ms) {
    if (noted) return;
    noted = true;
    info('[visphy] setupRecording(' + target + ', ' + ms + ' ms) called at t=' +
         performance.now().toFixed(1) + ' ms');
  }
  var real = window.setupRecording;
  if (typeof real !== 'function') return;
  window.setupRecording = function (canvas, durationMs) {
    note(describe(canvas), Number(durationMs));
    return real.apply(this, arguments);
  };
  var earlier = window.__visphy && window.__visphy.recording && window.__visphy.recording();
  if (earlier) note('(before the template)', earlier.durationMs);
})();
</script>"""
#: The note the probe leaves in the page log.
RECORDING_NOTE = "[visphy] setupRecording("

_SHARED_POOL: BrowserPool | None = None


def shared_pool() -> BrowserPool:
    """One Chromium pool per process, shared by every browser engine."""
    global _SHARED_POOL
    if _SHARED_POOL is None:
        _SHARED_POOL = BrowserPool()
    return _SHARED_POOL


def close_shared_pool() -> None:
    global _SHARED_POOL
    if _SHARED_POOL is not None:
        _SHARED_POOL.close()
        _SHARED_POOL = None


def tick_ms_for(fps: float) -> float:
    """Animation tick (≈60 Hz) that divides the frame period, so captures fall on ticks."""
    return 1000.0 / (fps * max(1, math.ceil(60.0 / fps)))


class BrowserEngine(Engine):
    language = "html"
    js_assets = BROWSER_ASSETS
    #: <script> tags the trusted template puts before the program (vendor short names).
    preload: tuple[str, ...] = ()
    #: How frames are read: "canvas" (main canvas readback) or "screenshot" (viewport).
    capture: str = "canvas"
    #: Whether 2D scenes get the cannon 2D constraint helper.
    constrain_2d: bool = True
    #: Whether the engine's instructions ask for ``setupRecording(canvas, durationMs)``: a page
    #: that never calls it is flagged ``no_recording_call``.
    expects_recording_call: bool = True
    #: The browser pool pages run in: None for the process' shared pool (`shared_pool`); a
    #: caller may set its own (e.g. a pool with ``readback="png"`` to compare render paths).
    pool: BrowserPool | None = None

    def cache_identity(self) -> str:
        """The engine's version plus the virtual clock's digest: a change to the clock (what a
        page sees of time, timers, messages) re-renders instead of replaying old clips."""
        from visphy_core.api.sandbox import VIRTUAL_TIME_JS

        clock = hashlib.sha256(VIRTUAL_TIME_JS.encode()).hexdigest()[:12]
        return f"{super().cache_identity()}+clock.{clock}"

    def extract(self, text: str) -> Program:
        source = extract_code(text, ("html", "htm", "xml"), html_fallback=True)
        return Program(language=self.language, source=source, spec=extract_spec(text))

    def validate(self, program: Program) -> None:
        if "<script" not in program.source.lower():
            raise ProgramRejected(FailureClass.NO_CODE, "the HTML program has no <script>")

    @cached_property
    def vendor(self):
        from visphy_core.api.sandbox import VendorFiles

        return VendorFiles(self.js_assets)

    @cached_property
    def assets(self):
        """The vendored files plus visphy's own generated/served helpers."""
        vendor = self.vendor
        overlay = {
            "vendor/cannon-es.js": CANNON_ES_WRAPPER,
        }
        # r187's three.module.js imports ./three.core.js: keep /vendor/three.module.js loadable.
        if "vendor/npm/three-esm/build/three.core.js" in vendor:
            overlay["vendor/three.core.js"] = vendor["vendor/npm/three-esm/build/three.core.js"]
        return ChainMap(overlay, vendor)

    def head_extras(self, dim: str) -> list[str]:
        """Engine-specific trusted markup after the libraries (before the program)."""
        return []

    def canonicalise(self, source: str, dim: str = "2d") -> str:
        """The program inside the trusted template: pinned libraries first, then the program
        (a page that loads its libraries itself, as upstream's pages do)."""
        return self.canonicalise_noted(source, dim)[0]

    def canonicalise_noted(self, source: str, dim: str = "2d", preload_tags: bool = True
                           ) -> tuple[str, list[Substitution]]:
        """`canonicalise`, and every library URL of the program it pointed at a vendored copy.
        ``preload_tags=False``: without the preloaded libraries' tags, for a page that runs them
        before its own scripts (`BrowserPool.render_page`'s ``preload``)."""
        preloaded = {f"/vendor/{name}" for name in self.preload}
        notes: list[Substitution | None] = []

        def script_tag(m: re.Match) -> str:
            attrs = (m.group(1) + " " + m.group(4)).lower()
            is_module = re.search(r"type\s*=\s*[\"']?module", attrs) is not None
            target = vendored_url(m.group(3), allow_local=True)
            if target is None:
                return m.group(0)
            if target in preloaded and not is_module:
                notes.append(_substitution(m.group(3), target, "preloaded"))
                return ""  # the template already loaded it
            notes.append(_substitution(m.group(3), target))
            return m.group(0).replace(m.group(3), target, 1)

        def url_literal(m: re.Match) -> str:
            target = vendored_url(m.group(2))
            if target is None:
                return m.group(0)
            notes.append(_substitution(m.group(2), target))
            return m.group(1) + target + m.group(1)

        body = _SCRIPT_SRC_TAG.sub(script_tag, source)
        body, import_map = _merge_import_maps(body, notes)
        body = _URL_LITERAL.sub(url_literal, body)
        head = ['<script type="importmap">' + json.dumps(import_map) + "</script>"]
        if preload_tags:
            head += [f'<script src="/vendor/{name}"></script>' for name in self.preload]
        if dim != "3d" and self.constrain_2d:
            head.append(f"<script>\n{constraint_2d_js()}</script>")
        head += self.head_extras(dim)
        if self.expects_recording_call:
            head.append(RECORDING_PROBE)
        injected = "\n".join(head)
        unique = list(dict.fromkeys(n for n in notes if n is not None))
        m = re.search(r"<head\b[^>]*>", body, re.I)
        if m:
            return body[: m.end()] + "\n" + injected + body[m.end():], unique
        m = re.search(r"<html\b[^>]*>", body, re.I)
        if m:
            return body[: m.end()] + "<head>" + injected + "</head>" + body[m.end():], unique
        return ("<!DOCTYPE html><html><head>" + injected + "</head><body>" + body
                + "</body></html>"), unique

    def render(self, program: Program, contract: RenderContract) -> RenderResult:
        capture, html, notes = self.capture_page(program, contract)
        result = classify_capture(capture, contract,
                                  expects_recording_call=self.expects_recording_call)
        self.note_libraries(result, notes, capture, html)
        return result

    def capture_page(self, program: Program, contract: RenderContract
                     ) -> tuple[PageCapture, str, list[Substitution]]:
        """Run the program's page (`render` without classifying): what the page did, the
        canonical HTML and its library notes. Benchmarks time the two halves apart."""
        html, notes = self.canonicalise_noted(program.source, contract.dim, preload_tags=False)
        capture = (self.pool or shared_pool()).render_page(
            html, self.assets, contract.frame_times_ms(), width=contract.width,
            height=contract.height, timeout_s=contract.timeout_s, seed=contract.seed,
            tick_ms=tick_ms_for(contract.fps), capture=self.capture,
            preload=[f"vendor/{name}" for name in self.preload])
        return capture, html, notes

    def note_libraries(self, result: RenderResult, notes: list[Substitution],
                       cap: PageCapture, html: str) -> None:
        """Log every library URL served from a vendored copy, flag other versions, and name
        the three.js builds of a page in which three.js saw two instances."""
        lines = [n.describe() for n in notes]
        if any(n.substituted for n in notes):
            result.flag(RenderFlag.LIBRARY_SUBSTITUTED)
        if any(THREE_TWICE in line for line in cap.console):
            builds: dict[str, str] = {}  # served path -> description
            for name in self.preload:
                hit = served_version(f"/vendor/{name}")
                if hit and hit[0] == "three":
                    builds[f"/vendor/{name}"] = f"three {hit[1]} (/vendor/{name}, preloaded)"
            for n in notes:
                if n.package == "three" and "/examples/jsm/" not in n.served:
                    builds.setdefault(n.served, f"three {n.served_version} ({n.served})")
            if _IMPORTS_THREE.search(html):
                hit = served_version(THREE_ESM)
                builds.setdefault(THREE_ESM, f"three {hit[1] if hit else '?'} ({THREE_ESM}, "
                                             "the ES module 'three')")
            lines.append("[visphy] two three.js instances were loaded in this page (three.js "
                         f"warned: {THREE_TWICE}); the page references "
                         + (", ".join(builds.values()) or "no vendored build"))
        from visphy_core.api.calls import redact

        result.logs += [redact(line) for line in lines]  # last: the cached log keeps its tail

    def close(self) -> None:
        close_shared_pool()


@functools.lru_cache(maxsize=1)
def constraint_2d_js() -> str:
    """The 2D constraint helper, inlined in a 2D page's head after its libraries."""
    return (TEMPLATES / "constraint2d.js").read_text()


def replay_payload_2d(scene, engine_name: str) -> dict:
    """The scene's replay payload (`visphy_core.spec.replay`) for a 2D-only engine."""
    if scene.dim == "3d":
        raise NotImplementedError(
            f"{scene.scene_id}: the {engine_name} engine is 2D only; a 3D scene has no "
            f"{engine_name} reference program (use engine=threejs for 3D scenes)")
    return replay_payload(scene)


def fill_template(name: str, payload: dict) -> str:
    return fill((TEMPLATES / name).read_text(), payload)


def _resize(frames: list[np.ndarray], contract: RenderContract) -> np.ndarray:
    from visphy_core.api.media import resize_with_padding

    return np.stack([resize_with_padding(f, contract.width, contract.height) for f in frames])


#: Blocked resource types that a library would have been: named "not vendored" in details.
_LIBRARY_REQUESTS = ("script", "stylesheet", "font", "other", "fetch", "xhr")
_ERROR_TIME = re.compile(r"\bat t=(\d+(?:\.\d+)?)ms")


def blocked_detail(blocked: list[str], limit: int = 3) -> str:
    """``"; blocked request(s): URL (not vendored), ..."`` for the passive requests the page
    was refused (its libraries, images...), or ``""``."""
    named = []
    for entry in blocked:
        kind, _, url = entry.partition(" ")
        if not url or kind in ACTIVE_REQUESTS:
            continue
        why = "not vendored" if kind in _LIBRARY_REQUESTS else f"{kind}: no network"
        named.append(f"{url} ({why})")
    named = list(dict.fromkeys(named))
    if not named:
        return ""
    more = f" and {len(named) - limit} more" if len(named) > limit else ""
    return "; blocked request(s): " + ", ".join(named[:limit]) + more


def _partial(cap: PageCapture, contract: RenderContract, first_error: str) -> np.ndarray | None:
    """Clip-sized frames captured at virtual times before the first error, or None."""
    m = _ERROR_TIME.search(first_error)
    if m is None:
        return None
    t = float(m.group(1))
    k = min(len(cap.frames), sum(1 for time_ms in contract.frame_times_ms() if time_ms < t))
    if not 0 < k < contract.n_frames:
        return None
    return _resize(cap.frames[:k], contract)


def classify_capture(cap: PageCapture, contract: RenderContract,
                     expects_recording_call: bool = False) -> RenderResult:
    """Turn what the page did into frames or a failure class, with the evidence in the logs,
    and the flags of what was done to it (`RenderFlag`; ``expects_recording_call``: flag a page
    that never called ``setupRecording``)."""
    from visphy_core.api.calls import redact, redact_obj

    logs = list(cap.errors) + list(cap.console)
    logs += [f"blocked request: {url}" for url in cap.blocked_requests]
    result = RenderResult(frames=None, logs=redact_obj(logs),
                          blocked_requests=redact_obj(list(cap.blocked_requests)),
                          wall_s=cap.wall_s, isolation=cap.isolation)
    active = [u for u in result.blocked_requests
              if u.split(" ", 1)[0] in ACTIVE_REQUESTS or u.split(" ", 1)[-1].startswith("file:")]
    blocked = redact(blocked_detail(result.blocked_requests))
    if cap.infra_error:
        result.failure, result.error = FailureClass.INFRA_ERROR, redact(cap.infra_error)
    elif cap.resource_limit:
        result.failure, result.error = FailureClass.RESOURCE_LIMIT, cap.resource_limit
    elif cap.navigations or any(u.split(" ", 1)[0] in ("navigation", "popup") for u in active):
        # before the timeout: a page that tried to leave is a violation whether or not the
        # blocked navigation then left it stuck past its time limit (that depends on the load)
        leaving = cap.navigations or [u for u in active
                                      if u.split(" ", 1)[0] in ("navigation", "popup")]
        result.failure = FailureClass.SANDBOX_VIOLATION
        result.error = f"the page tried to leave: {redact(leaving[0])}"
        if cap.timed_out:
            result.logs.append(f"[visphy] and then no result within {contract.timeout_s:g} s")
    elif cap.timed_out:
        result.failure = FailureClass.TIMEOUT
        result.error = f"no result within {contract.timeout_s:g} s (infinite loop?)"
    elif active:
        result.failure = FailureClass.SANDBOX_VIOLATION
        what = "network or file access" if not active[0].startswith("webrtc") else "WebRTC"
        result.error = f"{what} attempted: {active[0]}"
    elif cap.errors:
        first = cap.errors[0]
        syntax = "SyntaxError" in first
        result.failure = FailureClass.SYNTAX_ERROR if syntax else FailureClass.RUNTIME_ERROR
        result.error = redact(first) + blocked
        if not syntax:
            partial = _partial(cap, contract, first)
            if partial is not None:
                result.partial_frames = partial
                result.flag(RenderFlag.PARTIAL_CLIP)
                result.logs.append(f"[visphy] partial clip: {len(partial)} of "
                                   f"{contract.n_frames} frames were captured before the error")
    elif cap.no_canvas or len(cap.frames) < contract.n_frames:
        result.failure = FailureClass.BLANK_OUTPUT
        result.error = "the page has no canvas (or <svg>) to record" + blocked
    else:
        frames = _resize(cap.frames, contract)
        if classify_frames(frames) is FailureClass.BLANK_OUTPUT:
            result.failure = FailureClass.BLANK_OUTPUT
            result.error = "every frame is one flat colour" + blocked
        else:
            result.frames = frames
    if result.failure in (FailureClass.INFRA_ERROR, FailureClass.RESOURCE_LIMIT,
                          FailureClass.TIMEOUT):
        return result  # the page did not run to the end: nothing more to say about it
    sizes = list(dict.fromkeys(f.shape[:2] for f in cap.frames))
    odd = [hw for hw in sizes if hw != (contract.height, contract.width)]
    if odd:
        result.flag(RenderFlag.CANVAS_RESIZED)
        result.logs.append(f"[visphy] the recorded canvas is {odd[0][1]}x{odd[0][0]} px, not the "
                           f"clip's {contract.width}x{contract.height}: every frame was scaled "
                           "to fit (uniformly, centred, white bars)")
    if expects_recording_call and not any(RECORDING_NOTE in line for line in cap.console):
        result.flag(RenderFlag.NO_RECORDING_CALL)
        result.logs.append("[visphy] the page never called setupRecording(canvas, durationMs)"
                           + ("; its largest canvas was recorded" if cap.frames else ""))
    return result
