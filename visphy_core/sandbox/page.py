"""One page of a `visphy_core.sandbox.browser.BrowserPool`: what it produced (`PageCapture`),
what runs before its own scripts (`page_init`), and the steps of its render inside a prepared
page: load the program, wait until it is ready, capture its frames (canvas frames several per
call to the page, or viewport screenshots), and the renderer crash tests inject."""

from __future__ import annotations

import asyncio
import base64
import json
import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from visphy_core.sandbox.prepared import PageInit, PreparedPage
from visphy_core.sandbox.readback import frame_from_capture, png_bytes_to_rgb
from visphy_core.sandbox.routing import ORIGIN, Asset, asset_text, on_console, on_popup

VIRTUAL_TIME_JS = (Path(__file__).with_name("virtual_time.js")).read_text()

#: Real seconds a page may take, after its load event, to become ready (a library's own
#: asynchronous start-up).
READY_WAIT_S = 10.0
#: Canvas capture: the real time (ms) and the payload (characters of base64) one call to the
#: page may spend on frames before it hands them back (`capture_canvas`).
SPAN_BUDGET_MS = 150
SPAN_MAX_CHARS = 8 << 20


@dataclass
class PageCapture:
    """What one page produced: frames at the requested times, and what went wrong."""

    frames: list[np.ndarray] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    console: list[str] = field(default_factory=list)
    blocked_requests: list[str] = field(default_factory=list)
    timed_out: bool = False
    no_canvas: bool = False
    infra_error: str | None = None
    #: The page hit the memory cap (JS heap exhausted, or renderer killed by the watchdog).
    resource_limit: str | None = None
    #: The page tried to leave (navigation of the main frame, a pop-up): a sandbox violation.
    navigations: list[str] = field(default_factory=list)
    isolation: str | None = None
    wall_s: float = 0.0
    #: Seconds per phase: ``page`` (a context and page, prepared or made now), ``load``
    #: (navigation to the load event), ``ready``, ``frames`` (stepping and readback), ``decode``
    #: (host-side frame decoding, part of ``frames``), ``state``, ``close``.
    timings: dict = field(default_factory=dict)
    #: Canvas frames read as raw pixels (the others were PNG: translucent, other formats...).
    raw_frames: int = 0
    #: Calls to the page that brought canvas frames back (several frames per call).
    frame_calls: int = 0
    #: Whether the page was prepared ahead of this program (else made on demand).
    page_prepared: bool = False

    def block(self, entry: str) -> None:
        if len(self.blocked_requests) < 200 and entry not in self.blocked_requests[-20:]:
            self.blocked_requests.append(entry)

    def detached(self) -> "PageCapture":
        """A new capture holding what this one holds; this one is left empty.

        The page's handlers (its request router's slot, its ``console`` and ``popup``
        listeners) and the finished render's coroutine frame reference the capture the page
        wrote to, and they can outlive the page in reference cycles (Playwright's listeners,
        the stack traces it captures for its calls), which only the cyclic garbage collector
        frees: measured on a run of 40 scenes, 0.56 GiB of frames (12.8 MiB per 2D clip) waited
        there for a collection that did not come. The caller gets the copy; what stays behind
        holds no frame."""
        out = replace(self)
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, (list, dict)):
                setattr(self, f.name, type(value)())
        return out


def page_init(assets: Mapping[str, Asset], preload: Sequence[str], *, tick_ms: float,
              seed: int, capture: str, real_webrtc: bool = False) -> PageInit:
    """A page's init: the virtual clock with its configuration, then the sources of the
    ``preload`` paths of ``assets``, in order."""
    config = {"tickMs": tick_ms, "seed": seed, "capture": capture, "origin": ORIGIN,
              "realWebRTC": real_webrtc}
    scripts = [f"window.__VISPHY_CONFIG__ = {json.dumps(config)};\n{VIRTUAL_TIME_JS}"]
    for path in preload:
        key = path.lstrip("/")
        if key not in assets:
            raise ValueError(f"the preloaded library {path!r} is not among the page's assets")
        scripts.append(asset_text(assets[key]))
    return PageInit(tuple(scripts))


async def load_program(prepared: PreparedPage, html, assets, cap: PageCapture, left,
                       lap) -> None:
    """Load the program into the prepared page (until its load event)."""
    context, page = prepared.context, prepared.page
    cap.page_prepared = prepared.ahead
    prepared.slot.load(html, assets, cap)
    context.set_default_timeout(left() * 1000)
    context.set_default_navigation_timeout(left() * 1000)
    page.on("popup", lambda popup: on_popup(popup, cap))
    page.on("console", lambda msg: on_console(msg, cap))
    lap("page")

    await asyncio.wait_for(page.goto(f"{ORIGIN}/index.html", wait_until="load",
                                     timeout=left() * 1000), left())
    lap("load")


async def capture_frames(context, page, cap: PageCapture, times_ms, width, height, capture,
                         readback: str, inject_fault, crashed: list, deadline: float, left,
                         lap) -> None:
    """One frame per virtual time in ``times_ms``, into ``cap.frames``, once the page says it
    is ready: the canvas read back by the page, or a CDP screenshot of the page."""
    if capture == "canvas":
        await capture_canvas(context, page, cap, times_ms, readback, inject_fault, crashed,
                             deadline, left, lap)
        return
    await asyncio.wait_for(wait_ready(page, cap, deadline), left())
    lap("ready")
    cdp = None
    for i, t in enumerate(times_ms):
        if cap.navigations:
            break  # the page tried to leave: what is left of it is not the program's
        if i == 1 and inject_fault == "crash":
            await crash_renderer(context, page, crashed)
        info = await asyncio.wait_for(
            page.evaluate("t => window.__visphy.prepareScreenshot(t)", t), left())
        if not isinstance(info, dict) or not info.get("drawable"):
            cap.no_canvas = True
            break
        if cdp is None:
            cdp = await asyncio.wait_for(context.new_cdp_session(page), left())
        # CDP directly: Playwright's page.screenshot adds round trips (fonts, caret).
        # optimizeForSpeed: a faster zlib setting; the PNG is as lossless as before.
        shot = await asyncio.wait_for(cdp.send("Page.captureScreenshot", {
            "format": "png", "fromSurface": True,
            "optimizeForSpeed": readback == "raw",
            "clip": {"x": 0, "y": 0, "width": width, "height": height, "scale": 1}}),
            left())
        lap("frames")
        cap.frames.append(png_bytes_to_rgb(base64.b64decode(shot["data"])))
        lap("decode")
    shot = None  # noqa: F841 - a finished coroutine's frame may outlive it


async def capture_canvas(context, page, cap: PageCapture, times_ms, readback: str,
                         inject_fault, crashed: list, deadline: float, left, lap) -> None:
    """Canvas frames in spans: the page steps and reads back as many frames as fit in
    `SPAN_BUDGET_MS` of real time (and `SPAN_MAX_CHARS` of payload) per call, so a clip
    costs a few round trips, and a page that stalls or crashes keeps the frames it gave. The
    first call checks that the page is ready (else the host waits for it, `wait_ready`)."""
    done, first = 0, True
    lap("ready")  # (waiting, if any, is added to it below)
    while done < len(times_ms) and not cap.navigations:
        if done == 1 and inject_fault == "crash":
            await crash_renderer(context, page, crashed)
        # (with a crash to inject, the first span is the first frame alone)
        todo = times_ms[done:done + 1] if inject_fault == "crash" and done == 0 else \
            times_ms[done:]
        answer = await asyncio.wait_for(page.evaluate(
            "([ts, raw, ms, chars, first]) => window.__visphy.captureSpan(ts, raw, ms, chars, "
            "first)", [todo, readback == "raw", SPAN_BUDGET_MS, SPAN_MAX_CHARS, first]), left())
        if first and isinstance(answer, dict) and answer.get("notReady"):
            lap("frames")
            await asyncio.wait_for(wait_ready(page, cap, deadline), left())
            lap("ready")
            first = False
            continue
        first = False
        lap("frames")
        cap.frame_calls += 1
        shots = answer.get("frames") if isinstance(answer, dict) else None
        if not isinstance(shots, list) or not shots or len(shots) > len(todo):
            cap.no_canvas = True
            break
        for shot in shots:
            frame = frame_from_capture(shot)
            if frame is None:
                cap.no_canvas = True
                break
            cap.frames.append(frame)
            cap.raw_frames += "png" not in shot
        lap("decode")
        if cap.no_canvas:
            break
        done += len(shots)
    answer = shots = frame = shot = None  # noqa: F841 - a finished coroutine's frame may outlive it


async def crash_renderer(context, page, crashed: list) -> None:
    """Fault injection for tests: crash the page's renderer (CDP Page.crash), as an
    out-of-memory renderer would. The command never answers: wait for the crash event."""
    session = await context.new_cdp_session(page)
    send = asyncio.ensure_future(session.send("Page.crash"))
    end = time.perf_counter() + 5
    while not crashed and not send.done() and time.perf_counter() < end:
        await asyncio.sleep(0.01)
    send.cancel()
    try:
        await send
    except BaseException:
        pass  # the session died with the renderer


async def wait_ready(page, cap: PageCapture, deadline: float) -> None:
    """Poll the page's ready checks (real time) for up to `READY_WAIT_S`, within the page's
    ``deadline``: a library's asynchronous start-up finishes outside virtual time. A page still
    not ready is captured anyway (and noted)."""
    budget_s = min(READY_WAIT_S, deadline - time.perf_counter())
    end = time.perf_counter() + max(0.0, budget_s)
    while True:
        if await page.evaluate("() => window.__visphy.isReady()"):
            return
        if cap.blocked_requests:  # what it waits for will never arrive
            cap.console.append("[visphy] a request was blocked while the page was starting; "
                               "capturing without waiting for it to be ready")
            return
        if time.perf_counter() >= end:
            cap.console.append(f"[visphy] page not ready after {budget_s:.1f} s; capturing")
            return
        await asyncio.sleep(0.01)
