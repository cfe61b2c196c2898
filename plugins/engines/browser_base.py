"""What the browser engines (threejs, p5, svg) share: canonicalisation, rendering, classification.

The trusted template puts the pinned libraries and an import map in front of the program, and
points the program's own references to those libraries (CDN ``<script>`` tags, import maps, ES
module URLs) at the vendored copies: a preloaded library's tag is removed, any other known
library's URL is rewritten to ``/vendor/...`` (the page could not load a CDN anyway). For 2D scenes
it also injects the 2D constraint helper (``templates/constraint2d.js``) that keeps cannon bodies
in the x-y plane. The sandbox's virtual clock drives every frame.
"""

from __future__ import annotations

import json
import math
import re
from collections import ChainMap
from functools import cached_property
from pathlib import Path
from urllib.parse import urlparse

import numpy as np

from visphy_core.engine import (Engine, FailureClass, Program, ProgramRejected, RenderContract,
                                RenderResult, classify_frames)
from visphy_core.extract import extract_code, extract_spec
from visphy_core.sandbox.browser import BrowserPool, PageCapture

TEMPLATES = Path(__file__).with_name("templates")

THREE_ESM = "/vendor/npm/three-esm/build/three.module.js"
IMPORT_MAP = {
    "imports": {
        "three": THREE_ESM,
        "three/webgpu": "/vendor/npm/three-esm/build/three.webgpu.js",
        "three/tsl": "/vendor/npm/three-esm/build/three.tsl.js",
        "three/addons/": "/vendor/npm/three-esm/examples/jsm/",
        "three/examples/jsm/": "/vendor/npm/three-esm/examples/jsm/",
        "cannon-es": "/vendor/cannon-es.js",
    }
}

#: ``import ... from 'cannon-es'`` gets this wrapper: the real module (still reachable at
#: /vendor/npm/cannon-es/dist/cannon-es.js) with World.step patched by the 2D constraint helper
#: when the page has it (2D scenes).
CANNON_ES_REAL = "/vendor/npm/cannon-es/dist/cannon-es.js"
CANNON_ES_WRAPPER = f"""// visphy: cannon-es 0.20, with the 2D constraint helper in 2D scenes
export * from '{CANNON_ES_REAL}';
import {{ World }} from '{CANNON_ES_REAL}';
if (typeof window !== 'undefined' && window.__visphyConstrain2D) window.__visphyConstrain2D(World);
"""
CONSTRAINT_2D_URL = "/vendor/visphy/constraint2d.js"

#: Attempts a program makes on its own (script-driven), as opposed to passive resources (an
#: ``<img>`` or a ``<script>`` from another host is refused and logged, not a violation): any of
#: these, or any attempt on a ``file:`` URL, is a sandbox violation.
ACTIVE_REQUESTS = ("fetch", "xhr", "websocket", "eventsource", "ping", "webrtc", "navigation",
                   "popup", "file")

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


# ------------------------------------------------------------------ library URLs -> vendored copies

CDN_HOSTS = ("cdn.jsdelivr.net", "fastly.jsdelivr.net", "unpkg.com", "cdnjs.cloudflare.com",
             "esm.sh", "cdn.esm.sh", "esm.run", "cdn.skypack.dev", "ga.jspm.io", "jspm.dev",
             "cdn.jsdelivr.com", "threejs.org", "cdn.rawgit.com", "rawcdn.githack.com")
_PACKAGE_ALIASES = {"three": "three", "three.js": "three", "cannon": "cannon",
                    "cannon.js": "cannon", "cannon-es": "cannon-es", "p5": "p5", "p5.js": "p5",
                    "matter-js": "matter-js", "matter.js": "matter-js", "matter": "matter-js"}
_URL_LITERAL = re.compile(
    r"""(["'`])((?:https?:)?//(?:%s)/[^"'`\s]*)\1""" % "|".join(re.escape(h) for h in CDN_HOSTS),
    re.I)
_SCRIPT_SRC_TAG = re.compile(
    r"<script\b([^>]*?)\bsrc\s*=\s*([\"'])([^\"']*)\2([^>]*)>\s*</script>", re.I)
_IMPORT_MAP_TAG = re.compile(
    r"<script\b[^>]*\btype\s*=\s*[\"']?importmap[\"']?[^>]*>(.*?)</script>", re.I | re.S)


def _cdn_package(url: str) -> tuple[str, str] | None:
    """(package, path inside the package) of a CDN URL, or None for another host."""
    parsed = urlparse(url if "//" in url[:8] or url.startswith("http") else "https:" + url)
    host = (parsed.hostname or "").lower()
    if host not in CDN_HOSTS:
        return None
    parts = [p for p in parsed.path.split("/") if p]
    if host == "threejs.org":  # https://threejs.org/build/three.module.js
        return "three", "/".join(parts)
    if parts and parts[0] in ("npm", "gh"):
        parts = parts[1:]
    if parts and parts[0].startswith("npm:"):
        parts[0] = parts[0][4:]
    if len(parts) >= 2 and parts[0] == "ajax" and parts[1] == "libs":  # cdnjs: name/version/file
        parts = parts[2:]
        if len(parts) < 2:
            return None
        name, rest = parts[0], parts[2:]
    else:
        if parts and re.fullmatch(r"v\d+", parts[0]):  # esm.sh build prefix
            parts = parts[1:]
        if not parts:
            return None
        if parts[0].startswith("@") and len(parts) > 1:
            name, rest = parts[0] + "/" + parts[1], parts[2:]
        else:
            name, rest = parts[0], parts[1:]
        name = name.rsplit("@", 1)[0] if "@" in name[1:] else name
    pkg = _PACKAGE_ALIASES.get(name.lower())
    return (pkg, "/".join(rest)) if pkg else None


def _local_package(url: str) -> tuple[str, str] | None:
    """A library guessed from a non-CDN script path by its file name (``js/three.min.js``)."""
    name = url.rsplit("/", 1)[-1].split("?", 1)[0].lower()
    for pkg, pattern in (("cannon-es", r"cannon-es(\.min)?\.m?js"),
                         ("cannon", r"cannon(\.min)?\.js"),
                         ("three", r"three(\.module|\.min|\.module\.min)?\.m?js"),
                         ("p5", r"p5(\.sound)?(\.min)?\.js"),
                         ("matter-js", r"matter(-js)?(\.min)?\.js")):
        if re.fullmatch(pattern, name):
            return pkg, name
    return None


def vendored_url(url: str, allow_local: bool = False) -> str | None:
    """The fake-origin path serving a library URL (CDN or, with ``allow_local``, a bare file name
    such as ``three.min.js``), or None when it is not one of the pinned libraries."""
    hit = _cdn_package(url) or (_local_package(url) if allow_local else None)
    if hit is None:
        return None
    pkg, sub = hit
    base = sub.lower().rstrip("/").rsplit("/", 1)[-1]  # file name ("" for the bare package)
    if not base.endswith((".mjs", ".js", ".cjs")) and base not in ("build", "dist", "lib", "+esm"):
        base = ""  # a package-level URL: https://esm.sh/three@0.160.0, .../es2022/…
    if pkg == "three":
        for marker in ("examples/jsm/", "addons/"):
            if marker in sub:
                return "/vendor/npm/three-esm/examples/jsm/" + sub.split(marker, 1)[1]
        if sub.rstrip("/").endswith(("examples/jsm", "addons")):
            return "/vendor/npm/three-esm/examples/jsm/"
        if base in ("three.min.js", "three.js", "three.cjs"):
            return "/vendor/three.min.js"
        if base.startswith("three.webgpu"):
            return "/vendor/npm/three-esm/build/three.webgpu.js"
        if base.startswith("three.tsl"):
            return "/vendor/npm/three-esm/build/three.tsl.js"
        if base == "three.core.js":
            return "/vendor/npm/three-esm/build/three.core.js"
        if base in ("", "build", "+esm", "three.module.js", "three.module.min.js", "three.mjs",
                    "index.js"):
            return THREE_ESM  # the ES module, also the bare package on esm.sh / skypack
        return None  # e.g. examples/js/… (classic add-ons, not vendored)
    if pkg == "cannon-es":
        ok = base in ("", "dist", "+esm") or base.startswith("cannon-es")
        return "/vendor/cannon-es.js" if ok else None
    if pkg == "cannon":
        ok = base in ("", "build") or base.startswith("cannon")
        return "/vendor/cannon.min.js" if ok else None
    if pkg == "p5":
        if "sound" in base:
            return "/vendor/npm/p5/lib/addons/p5.sound.min.js"
        ok = base in ("", "lib") or base in ("p5.js", "p5.min.js")
        return "/vendor/p5.min.js" if ok else None
    if pkg == "matter-js":
        ok = base in ("", "build") or base.startswith("matter")
        return "/vendor/matter.min.js" if ok else None
    return None


def _merge_import_maps(body: str) -> tuple[str, dict]:
    """Remove the program's import maps and merge them under ours (ours win on conflicts)."""
    merged = {"imports": dict(IMPORT_MAP["imports"])}
    theirs: dict = {"imports": {}, "scopes": {}}

    def take(m: re.Match) -> str:
        try:
            data = json.loads(m.group(1))
        except json.JSONDecodeError:
            return m.group(0)  # malformed: left for the browser to report
        if isinstance(data, dict):
            theirs["imports"].update(data.get("imports") or {})
            theirs["scopes"].update(data.get("scopes") or {})
        return ""

    body = _IMPORT_MAP_TAG.sub(take, body)
    for key, value in theirs["imports"].items():
        if isinstance(value, str):
            merged["imports"].setdefault(key, vendored_url(value) or value)
    if theirs["scopes"]:
        merged["scopes"] = theirs["scopes"]
    return body, merged


class BrowserEngine(Engine):
    language = "html"
    #: <script> tags the trusted template puts before the program (vendor short names).
    preload: tuple[str, ...] = ()
    #: How frames are read: "canvas" (main canvas readback) or "screenshot" (viewport).
    capture: str = "canvas"
    #: Whether 2D scenes get the cannon 2D constraint helper.
    constrain_2d: bool = True

    def extract(self, text: str) -> Program:
        source = extract_code(text, ("html", "htm", "xml"), html_fallback=True)
        return Program(language=self.language, source=source, spec=extract_spec(text))

    def validate(self, program: Program) -> None:
        if "<script" not in program.source.lower():
            raise ProgramRejected(FailureClass.NO_CODE, "the HTML program has no <script>")

    @cached_property
    def vendor(self):
        from visphy_core.js_assets import VendorFiles

        return VendorFiles()

    @cached_property
    def assets(self):
        """The vendored files plus visphy's own generated/served helpers."""
        vendor = self.vendor
        overlay = {
            "vendor/cannon-es.js": CANNON_ES_WRAPPER,
            CONSTRAINT_2D_URL.lstrip("/"): TEMPLATES / "constraint2d.js",
        }
        # r187's three.module.js imports ./three.core.js: keep /vendor/three.module.js loadable.
        if "vendor/npm/three-esm/build/three.core.js" in vendor:
            overlay["vendor/three.core.js"] = vendor["vendor/npm/three-esm/build/three.core.js"]
        return ChainMap(overlay, vendor)

    def head_extras(self, dim: str) -> list[str]:
        """Engine-specific trusted markup after the libraries (before the program)."""
        return []

    def canonicalise(self, source: str, dim: str = "2d") -> str:
        """The program inside the trusted template: pinned libraries first, then the program."""
        preloaded = {f"/vendor/{name}" for name in self.preload}

        def script_tag(m: re.Match) -> str:
            attrs = (m.group(1) + " " + m.group(4)).lower()
            is_module = re.search(r"type\s*=\s*[\"']?module", attrs) is not None
            target = vendored_url(m.group(3), allow_local=True)
            if target is None:
                return m.group(0)
            if target in preloaded and not is_module:
                return ""  # the template already loaded it
            return m.group(0).replace(m.group(3), target, 1)

        body = _SCRIPT_SRC_TAG.sub(script_tag, source)
        body, import_map = _merge_import_maps(body)
        body = _URL_LITERAL.sub(
            lambda m: (m.group(1) + (vendored_url(m.group(2)) or m.group(2)) + m.group(1)), body)
        head = ['<script type="importmap">' + json.dumps(import_map) + "</script>"]
        head += [f'<script src="/vendor/{name}"></script>' for name in self.preload]
        if dim != "3d" and self.constrain_2d:
            head.append(f'<script src="{CONSTRAINT_2D_URL}"></script>')
        head += self.head_extras(dim)
        injected = "\n".join(head)
        m = re.search(r"<head\b[^>]*>", body, re.I)
        if m:
            return body[: m.end()] + "\n" + injected + body[m.end():]
        m = re.search(r"<html\b[^>]*>", body, re.I)
        if m:
            return body[: m.end()] + "<head>" + injected + "</head>" + body[m.end():]
        return "<!DOCTYPE html><html><head>" + injected + "</head><body>" + body + "</body></html>"

    def render(self, program: Program, contract: RenderContract) -> RenderResult:
        capture = shared_pool().render_page(
            self.canonicalise(program.source, contract.dim), self.assets,
            contract.frame_times_ms(), width=contract.width, height=contract.height,
            timeout_s=contract.timeout_s, seed=contract.seed, tick_ms=tick_ms_for(contract.fps),
            capture=self.capture)
        return classify_capture(capture, contract)

    def close(self) -> None:
        close_shared_pool()


def replay_payload_2d(scene, engine_name: str) -> dict:
    """What a 2D reference program replays: size, fps, background, each body's colour and local
    geometry (a circle radius, or convex polygons in px around the body origin, y up) and the
    ground-truth poses [frame][body] = [x_px, y_px, angle_rad] (origin bottom-left, y up, CCW)."""
    from visphy_core.spec2d import local_polygons

    spec, traj = scene.spec, scene.trajectory
    if scene.dim == "3d":
        raise NotImplementedError(
            f"{scene.scene_id}: the {engine_name} engine is 2D only; a 3D scene has no "
            f"{engine_name} reference program (use engine=threejs for 3D scenes)")
    if spec is None or traj is None:
        raise ValueError(f"{scene.scene_id}: the reference program needs the scene's spec and "
                         "trajectory (generated benchmarks have both)")
    order = {str(body_id): i for i, body_id in enumerate(traj["body_ids"])}
    bodies = []
    for b in spec["bodies"]:
        shape = b["shape"]
        entry = {"id": b["id"], "color_rgb": [int(c) for c in b["color_rgb"]]}
        if shape["type"] == "circle":
            entry["radius"] = float(shape["radius_px"])
        else:
            entry["polygons"] = [[[round(float(v), 6) for v in pt] for pt in poly]
                                 for poly in local_polygons(shape)]
        bodies.append(entry)
    return {
        "width": scene.clip.width, "height": scene.clip.height, "fps": scene.clip.fps,
        "n_frames": scene.clip.n_frames,
        "background_rgb": [int(c) for c in spec.get("render", {}).get("background_rgb",
                                                                        [255, 255, 255])],
        "bodies": bodies,
        "frame_poses": [[[round(float(v), 6) for v in frame[order[b["id"]]]]
                         for b in spec["bodies"]] for frame in traj["frame_poses"]],
    }


def fill_template(name: str, payload: dict) -> str:
    html = (TEMPLATES / name).read_text()
    return html.replace("__SCENE_JSON__", json.dumps(payload, separators=(",", ":")))


def _resize(frames: list[np.ndarray], contract: RenderContract) -> np.ndarray:
    from visphy_core.video import resize_with_padding

    return np.stack([resize_with_padding(f, contract.width, contract.height) for f in frames])


def classify_capture(cap: PageCapture, contract: RenderContract) -> RenderResult:
    """Turn what the page did into frames or a failure class, with the evidence in the logs."""
    from visphy_core.secrets import redact, redact_obj

    logs = list(cap.errors) + list(cap.console)
    logs += [f"blocked request: {url}" for url in cap.blocked_requests]
    result = RenderResult(frames=None, logs=redact_obj(logs),
                          blocked_requests=redact_obj(list(cap.blocked_requests)),
                          wall_s=cap.wall_s, isolation=cap.isolation)
    active = [u for u in result.blocked_requests
              if u.split(" ", 1)[0] in ACTIVE_REQUESTS or u.split(" ", 1)[-1].startswith("file:")]
    if cap.infra_error:
        result.failure, result.error = FailureClass.INFRA_ERROR, redact(cap.infra_error)
    elif cap.resource_limit:
        result.failure, result.error = FailureClass.RESOURCE_LIMIT, cap.resource_limit
    elif cap.timed_out:
        result.failure = FailureClass.TIMEOUT
        result.error = f"no result within {contract.timeout_s:g} s (infinite loop?)"
    elif cap.navigations or any(u.split(" ", 1)[0] in ("navigation", "popup") for u in active):
        leaving = cap.navigations or [u for u in active
                                      if u.split(" ", 1)[0] in ("navigation", "popup")]
        result.failure = FailureClass.SANDBOX_VIOLATION
        result.error = f"the page tried to leave: {redact(leaving[0])}"
    elif active:
        result.failure = FailureClass.SANDBOX_VIOLATION
        what = "network or file access" if not active[0].startswith("webrtc") else "WebRTC"
        result.error = f"{what} attempted: {active[0]}"
    elif cap.errors:
        first = cap.errors[0]
        syntax = "SyntaxError" in first
        result.failure = FailureClass.SYNTAX_ERROR if syntax else FailureClass.RUNTIME_ERROR
        result.error = redact(first)
    elif cap.no_canvas or len(cap.frames) < contract.n_frames:
        result.failure = FailureClass.BLANK_OUTPUT
        result.error = "the page has no canvas (or <svg>) to record"
    else:
        frames = _resize(cap.frames, contract)
        if classify_frames(frames) is FailureClass.BLANK_OUTPUT:
            result.failure = FailureClass.BLANK_OUTPUT
            result.error = "every frame is one flat colour"
        else:
            result.frames = frames
    return result
