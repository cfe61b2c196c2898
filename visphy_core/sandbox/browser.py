"""A pool of headless Chromium instances (Debian's ``chromium``) driven by Playwright.

Why async Playwright on a private thread: a model-written page can hang its renderer with an
infinite loop, and the sync API cannot time out a blocked ``evaluate``. The pool runs one event
loop in a background thread; callers use the blocking ``render_page`` and get a watchdog for free.

Isolation: the page is served from a fixed fake origin through request interception, so Chromium
opens no socket for it; every other request (any host, any scheme that reaches the network stack)
is aborted and logged. DNS is mapped to nothing, background networking is off.

Capture modes: ``"canvas"`` reads the page's main canvas back as PNG (``toDataURL``) at each
virtual time; ``"screenshot"`` advances virtual time, seeks the document's animations (SMIL, CSS,
Web Animations) to it, and screenshots the viewport clipped to width×height (pages without a
canvas: SVG, DOM).
"""

from __future__ import annotations

import asyncio
import base64
import io
import json
import mimetypes
import os
import shutil
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Union
from urllib.parse import urlparse

import numpy as np

ORIGIN_HOST = "visphy.invalid"
ORIGIN = f"https://{ORIGIN_HOST}"
VIRTUAL_TIME_JS = (Path(__file__).with_name("virtual_time.js")).read_text()
CAPTURE_MODES = ("canvas", "screenshot")
#: Real seconds a page may take, after its load event, to become ready (e.g. p5's preload()).
READY_WAIT_S = 10.0

#: What the fake origin serves for a path: a file, or the content itself (generated wrappers).
Asset = Union[Path, bytes, str]

CHROMIUM_ARGS = [
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-default-apps",
    "--disable-extensions",
    "--mute-audio",
    "--host-resolver-rules=MAP * ~NOTFOUND",
    "--force-color-profile=srgb",
    "--disable-gpu-rasterization",
    # Screenshot mode: a captured frame must not depend on which paints happened before it in
    # real time (partial raster re-rasters only the damaged part of a tile; compositor-driven
    # animations pick their raster scale by timing). Canvas readback is unaffected by both.
    "--disable-partial-raster",
    "--disable-threaded-animation",
]


class BrowserUnavailable(RuntimeError):
    """Chromium or Playwright is missing or would not start."""


def find_chromium() -> str:
    """Path of the Chromium binary: $VISPHY_CHROMIUM, else Debian's /usr/bin/chromium."""
    candidates = [os.environ.get("VISPHY_CHROMIUM"), shutil.which("chromium"),
                  "/usr/bin/chromium", shutil.which("chromium-browser")]
    for path in candidates:
        if path and Path(path).is_file():
            return path
    raise BrowserUnavailable(
        "Chromium not found: install Debian's package (`apt-get install chromium`, done by "
        "`make setup`) or set VISPHY_CHROMIUM to the binary"
    )


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
    wall_s: float = 0.0


def _png_to_rgb(data_url: str) -> np.ndarray:
    from PIL import Image

    raw = base64.b64decode(data_url.split(",", 1)[1])
    img = Image.open(io.BytesIO(raw))
    img.load()
    if img.mode != "RGBA":
        img = img.convert("RGBA")
    # Transparent canvas pixels are shown as the white page behind them.
    white = Image.new("RGBA", img.size, (255, 255, 255, 255))
    return np.asarray(Image.alpha_composite(white, img).convert("RGB"))


def _png_bytes_to_rgb(png: bytes) -> np.ndarray:
    from PIL import Image

    img = Image.open(io.BytesIO(png))
    img.load()
    return np.asarray(img.convert("RGB"))


class BrowserPool:
    """Reusable Chromium processes; a fresh browser context per page; restart after a crash."""

    def __init__(self, size: int = 1, extra_args: list[str] | None = None,
                 restart_every: int = 200):
        self.size = size
        self.extra_args = extra_args or []
        self.restart_every = restart_every
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True,
                                        name="visphy-browser-pool")
        self._thread.start()
        self._playwright = None
        self._browsers: list = []
        self._uses = 0
        self._next = 0
        self.restarts = 0

    # ---------------------------------------------------------------- lifecycle

    def _run(self, coro, timeout: float | None = None):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    async def _start(self) -> None:
        from playwright.async_api import async_playwright

        executable = find_chromium()
        if self._playwright is None:
            self._playwright = await async_playwright().start()
        while len(self._browsers) < self.size:
            try:
                browser = await self._playwright.chromium.launch(
                    executable_path=executable, headless=True,
                    args=CHROMIUM_ARGS + self.extra_args, env=_scrubbed_env())
            except Exception as exc:
                raise BrowserUnavailable(
                    f"Chromium at {executable} failed to start: {exc}") from exc
            self._browsers.append(browser)

    async def _restart(self) -> None:
        browsers, self._browsers = self._browsers, []
        for browser in browsers:
            try:
                await asyncio.wait_for(browser.close(), 10)
            except Exception:
                pass
        if self._playwright is not None:
            try:
                await asyncio.wait_for(self._playwright.stop(), 10)
            except Exception:
                pass
            self._playwright = None
        self.restarts += 1
        await self._start()

    def close(self) -> None:
        async def _close():
            for browser in self._browsers:
                try:
                    await asyncio.wait_for(browser.close(), 10)
                except Exception:
                    pass
            self._browsers = []
            if self._playwright is not None:
                await self._playwright.stop()
                self._playwright = None

        if self._thread.is_alive():
            try:
                self._run(_close(), timeout=30)
            finally:
                self._loop.call_soon_threadsafe(self._loop.stop)
                self._thread.join(timeout=5)

    def __enter__(self) -> "BrowserPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- rendering

    def render_page(self, html: str, assets: Mapping[str, Asset], times_ms: list[float], *,
                    width: int, height: int, timeout_s: float, seed: int = 0,
                    tick_ms: float = 1000 / 60, capture: str = "canvas",
                    inject_fault: str | None = None) -> PageCapture:
        """Load ``html`` at the fake origin and capture a frame at each virtual time.

        ``assets`` maps URL paths (``vendor/...``) to files or to their content (bytes/str).
        ``capture``: ``"canvas"`` reads back the main canvas; ``"screenshot"`` screenshots the
        viewport (0, 0, width, height) after seeking document animations to the virtual time.
        ``inject_fault="crash"`` (tests only) crashes the renderer after the first frame.
        """
        if capture not in CAPTURE_MODES:
            raise ValueError(f"capture must be one of {CAPTURE_MODES}, not {capture!r}")
        return self._run(self._render(html, assets, times_ms, width, height,
                                      timeout_s, seed, tick_ms, capture, inject_fault))

    async def _render(self, html, assets, times_ms, width, height, timeout_s, seed, tick_ms,
                      capture="canvas", inject_fault=None):
        if not self._browsers or self._uses >= self.restart_every:
            if self._uses >= self.restart_every:
                await self._restart()
                self._uses = 0
            else:
                await self._start()
        browser = self._browsers[self._next % len(self._browsers)]
        self._next += 1
        if not browser.is_connected():
            await self._restart()
            browser = self._browsers[0]
        self._uses += 1
        cap = PageCapture()
        start = time.perf_counter()
        context = None
        crashed: list[bool] = []
        cdp = None
        try:
            context = await browser.new_context(
                viewport={"width": width, "height": height}, device_scale_factor=1,
                service_workers="block", accept_downloads=False)
            await context.route("**/*", self._router(html, assets, cap))
            config = {"tickMs": tick_ms, "seed": seed, "capture": capture}
            await context.add_init_script(
                f"window.__VISPHY_CONFIG__ = {json.dumps(config)};\n{VIRTUAL_TIME_JS}")
            page = await context.new_page()
            page.on("crash", lambda _page: crashed.append(True))
            deadline = start + timeout_s

            def left() -> float:
                return max(0.1, deadline - time.perf_counter())

            await asyncio.wait_for(page.goto(f"{ORIGIN}/index.html", wait_until="load"), left())
            await asyncio.wait_for(self._wait_ready(
                page, cap, min(READY_WAIT_S, deadline - time.perf_counter())), left())
            for i, t in enumerate(times_ms):
                if i == 1 and inject_fault == "crash":
                    await self._crash_renderer(context, page, crashed)
                if capture == "canvas":
                    shot = await asyncio.wait_for(
                        page.evaluate("t => window.__visphy.captureAt(t)", t), left())
                    if not shot or not shot.get("png"):
                        cap.no_canvas = True
                        break
                    cap.frames.append(_png_to_rgb(shot["png"]))
                else:
                    info = await asyncio.wait_for(
                        page.evaluate("t => window.__visphy.prepareScreenshot(t)", t), left())
                    if not info or not info.get("drawable"):
                        cap.no_canvas = True
                        break
                    if cdp is None:
                        cdp = await context.new_cdp_session(page)
                    # CDP directly: Playwright's page.screenshot adds round trips (fonts, caret).
                    shot = await asyncio.wait_for(cdp.send("Page.captureScreenshot", {
                        "format": "png", "fromSurface": True,
                        "clip": {"x": 0, "y": 0, "width": width, "height": height, "scale": 1}}),
                        left())
                    cap.frames.append(_png_bytes_to_rgb(base64.b64decode(shot["data"])))
            state = await asyncio.wait_for(
                page.evaluate("() => [window.__visphy.errors(), window.__visphy.logs()]"),
                max(0.1, deadline - time.perf_counter()))
            cap.errors.extend(state[0])
            cap.console.extend(state[1])
        except asyncio.TimeoutError:
            if crashed:
                cap.infra_error = "browser failure: the renderer crashed"
            else:
                cap.timed_out = True
        except Exception as exc:  # crash of the renderer or of the browser: infra, not the program
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if (crashed or "crash" in msg.lower() or "has been closed" in msg
                    or not browser.is_connected()):
                cap.infra_error = f"browser failure: {msg}"
            else:
                cap.errors.append(f"page failure: {msg}")
        finally:
            restart = False
            if context is not None:
                try:
                    await asyncio.wait_for(context.close(), 10)
                except Exception:
                    restart = True
            # A crashed renderer takes only its page down; restart when the browser went too.
            if cap.infra_error and not browser.is_connected():
                restart = True
            if restart:
                await self._restart()
        cap.wall_s = time.perf_counter() - start
        return cap

    @staticmethod
    async def _crash_renderer(context, page, crashed: list) -> None:
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

    @staticmethod
    async def _wait_ready(page, cap: PageCapture, budget_s: float) -> None:
        """Poll the page's ready checks (real time): asynchronous start-up such as p5's preload()
        finishes outside virtual time. A page still not ready is captured anyway (and noted)."""
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

    @staticmethod
    def _router(html: str, assets: Mapping[str, Asset], cap: PageCapture):
        async def handle(route):
            url = route.request.url
            parsed = urlparse(url)
            if parsed.hostname == ORIGIN_HOST:
                path = parsed.path.lstrip("/")
                if path == "index.html":
                    await route.fulfill(status=200, body=html.encode(),
                                        content_type="text/html; charset=utf-8")
                    return
                if path in assets:
                    item = assets[path]
                    name = Path(path).name
                    ctype = mimetypes.guess_type(name)[0] or "application/octet-stream"
                    if Path(name).suffix in (".js", ".mjs", ".cjs"):
                        ctype = "text/javascript"
                    if isinstance(item, Path):
                        body = item.read_bytes()
                    else:
                        body = item.encode() if isinstance(item, str) else bytes(item)
                    await route.fulfill(status=200, body=body, content_type=ctype)
                    return
                cap.blocked_requests.append(f"{route.request.resource_type} {url[:300]}")
                await route.fulfill(status=404, body=b"not vendored", content_type="text/plain")
                return
            if len(cap.blocked_requests) < 200:
                cap.blocked_requests.append(f"{route.request.resource_type} {url[:300]}")
            await route.abort("blockedbyclient")

        return handle


def _scrubbed_env() -> dict[str, str]:
    """Chromium sees no API keys or tokens from the parent environment."""
    keep = ("PATH", "HOME", "LANG", "LC_ALL", "TZ", "FONTCONFIG_PATH", "XDG_RUNTIME_DIR", "TMPDIR")
    env = {k: v for k, v in os.environ.items() if k in keep}
    env.setdefault("TZ", "UTC")
    return env
