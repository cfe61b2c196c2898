"""What the browser engines (threejs, p5, svg) share: canonicalisation, rendering, classification.

The trusted template puts the pinned libraries and an import map in front of the program, removes
the program's own CDN tags for those libraries (the page could not load them anyway), and the
sandbox's virtual clock drives every frame.
"""

from __future__ import annotations

import math
import re
from functools import cached_property

import numpy as np

from visphy_core.engine import (Engine, FailureClass, Program, ProgramRejected, RenderContract,
                                RenderResult, classify_frames)
from visphy_core.extract import extract_code, extract_spec
from visphy_core.sandbox.browser import BrowserPool, PageCapture

IMPORT_MAP = {
    "imports": {
        "three": "/vendor/three.module.js",
        "three/addons/": "/vendor/npm/three-esm/examples/jsm/",
        "three/examples/jsm/": "/vendor/npm/three-esm/examples/jsm/",
        "cannon-es": "/vendor/cannon-es.js",
    }
}

_CDN_LIBRARY_TAG = re.compile(
    r"<script\b[^>]*\bsrc\s*=\s*[\"'][^\"']*(three|cannon|p5|matter)[^\"']*[\"'][^>]*>\s*</script>",
    re.I)

#: Requests a program makes on its own (script-driven), as opposed to passive resources.
ACTIVE_REQUESTS = ("fetch", "xhr", "websocket", "eventsource")

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
    #: <script> tags the trusted template puts before the program (vendor short names).
    preload: tuple[str, ...] = ()

    def extract(self, text: str) -> Program:
        source = extract_code(text, ("html", "htm", "xml"), html_fallback=True)
        return Program(language=self.language, source=source, spec=extract_spec(text))

    def validate(self, program: Program) -> None:
        if "<script" not in program.source.lower():
            raise ProgramRejected(FailureClass.NO_CODE, "the HTML program has no <script>")

    @cached_property
    def vendor(self):
        from visphy_plugins.engines.js_assets import VendorFiles

        return VendorFiles()

    def canonicalise(self, source: str) -> str:
        """The program inside the trusted template: pinned libraries first, then the program."""
        import json

        body = _CDN_LIBRARY_TAG.sub("", source)
        head = ['<script type="importmap">' + json.dumps(IMPORT_MAP) + "</script>"]
        head += [f'<script src="/vendor/{name}"></script>' for name in self.preload]
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
            self.canonicalise(program.source), self.vendor, contract.frame_times_ms(),
            width=contract.width, height=contract.height, timeout_s=contract.timeout_s,
            seed=contract.seed, tick_ms=tick_ms_for(contract.fps))
        return classify_capture(capture, contract)

    def close(self) -> None:
        close_shared_pool()


def _resize(frames: list[np.ndarray], contract: RenderContract) -> np.ndarray:
    from visphy_core.video import resize_with_padding

    return np.stack([resize_with_padding(f, contract.width, contract.height) for f in frames])


def classify_capture(cap: PageCapture, contract: RenderContract) -> RenderResult:
    """Turn what the page did into frames or a failure class, with the evidence in the logs."""
    logs = list(cap.errors) + list(cap.console)
    logs += [f"blocked request: {url}" for url in cap.blocked_requests]
    result = RenderResult(frames=None, logs=logs, blocked_requests=list(cap.blocked_requests),
                          wall_s=cap.wall_s)
    active = [u for u in cap.blocked_requests if u.split(" ", 1)[0] in ACTIVE_REQUESTS]
    if cap.infra_error:
        result.failure, result.error = FailureClass.INFRA_ERROR, cap.infra_error
    elif cap.timed_out:
        result.failure = FailureClass.TIMEOUT
        result.error = f"no result within {contract.timeout_s:g} s (infinite loop?)"
    elif active:
        result.failure = FailureClass.SANDBOX_VIOLATION
        result.error = f"network access attempted: {active[0]}"
    elif cap.errors:
        first = cap.errors[0]
        syntax = "SyntaxError" in first
        result.failure = FailureClass.SYNTAX_ERROR if syntax else FailureClass.RUNTIME_ERROR
        result.error = first
    elif cap.no_canvas or len(cap.frames) < contract.n_frames:
        result.failure, result.error = FailureClass.BLANK_OUTPUT, "the page has no canvas to record"
    else:
        frames = _resize(cap.frames, contract)
        if classify_frames(frames) is FailureClass.BLANK_OUTPUT:
            result.failure, result.error = FailureClass.BLANK_OUTPUT, "every frame is one flat colour"
        else:
            result.frames = frames
    return result
