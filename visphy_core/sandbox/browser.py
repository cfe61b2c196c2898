"""A pool of headless Chromium instances (Debian's ``chromium``) driven by Playwright.

Why async Playwright on a private thread: a model-written page can hang its renderer with an
infinite loop, and the sync API cannot time out a blocked ``evaluate``. The pool runs one event
loop in a background thread; callers use the blocking ``render_page`` and get a watchdog for free.

Isolation, in layers (the first is the one that holds; the others make attempts visible):

* **Network namespace**: Chromium itself runs in a fresh, empty network namespace (``unshare -n``
  as root, ``unshare -rn`` otherwise): not even loopback is up, so no socket of the browser, its
  renderers, workers or WebRTC can reach the host or anything else. Playwright talks to Chromium
  over a pipe and the page's own files are fulfilled by request interception, without sockets.
  Whether the kernel grants the namespace is probed once; without it untrusted pages are refused
  (`SandboxUnavailable`) unless the user opted out (`configure(allow_unisolated=True)`, config key
  ``sandbox.allow_unisolated``, or ``VISPHY_ALLOW_UNISOLATED=1``). `browser_isolation_level()`
  says which level applies; every `PageCapture` records it.
* **Request interception**: the page is served from a fixed fake origin; every other request
  (any host, WebSocket, EventSource, beacons, navigations away, pop-ups) is refused and logged.
  WebRTC is off (Chromium policy: no non-proxied UDP; ``RTCPeerConnection`` throws), and the
  virtual-time script logs script-level attempts the network layer never sees (``file://``).
* **Resource caps**: a JavaScript heap limit (``--max-old-space-size``) and a watchdog on the
  resident memory of the page's renderer (and the GPU process) that kills it above the cap; either
  ends the page as ``resource_limit``. Every wait has the page's deadline; at the deadline a stuck
  renderer is killed so the pool stays usable.
* **Environment**: Chromium starts from an allow-listed environment (no secrets) with a private
  ``HOME``.

Capture modes: ``"canvas"`` reads the page's main canvas back at each virtual time: as raw
pixels where that is exact (`visphy_core.sandbox.readback`; ``readback="png"`` keeps the PNG-only
path of ``toDataURL``); ``"screenshot"`` advances virtual time, seeks the document's animations
(SMIL, CSS, Web Animations) to it, and screenshots the viewport clipped to width×height (pages
without a canvas: SVG, DOM).

Set-up is paid ahead (`visphy_core.sandbox.prepared`): after each page the pool prepares the
next one, a fresh context whose init (the virtual clock, then the libraries the engine preloads:
``preload``) is registered and already compiled in its renderer, and closes the finished context
in the background. Every `PageCapture` records how
long each phase took (``timings``).
"""
# size: one pool: its thread, its browsers (launch, restart, watchdog), a page's life

from __future__ import annotations

import asyncio
import os
import shutil
import tempfile
import threading
import time
import weakref
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Mapping, Sequence

from visphy_core.sandbox.chromium import (
    CHROMIUM_UID,
    MERGE_FEATURES_SH,
    ChromiumProcess,
    bwrap_for_chromium,
    bwrap_launcher,
    chromium_env,
    kill_all,
    netns_prefix,
    rss_bytes,
    sh_quote,
)
from visphy_core.sandbox.page import (  # noqa: F401 - PageCapture and the clock: public here
    VIRTUAL_TIME_JS,
    PageCapture,
    capture_frames,
    load_program,
    page_init,
)
from visphy_core.sandbox.policy import (
    ALLOW_UNISOLATED_ENV,
    set_allow_unisolated,
    unisolated_allowed,
)
from visphy_core.sandbox.prepared import PageInit, PreparedPage, discard, open_page
from visphy_core.sandbox.routing import Asset

CAPTURE_MODES = ("canvas", "screenshot")
#: How canvas frames are read: raw pixels where exact (else PNG), or always PNG (the old path).
READBACK_MODES = ("raw", "png")
#: Per-page memory cap (MB): resident memory of the page's renderer (and of the GPU process).
DEFAULT_MEMORY_MB = 2048
#: Seconds between two looks of the memory watchdog at the renderer processes.
WATCH_INTERVAL_S = 0.1
#: Isolation level recorded when Chromium runs in its own empty network namespace.
ISOLATION_NETNS = "chromium:netns,no-egress"
#: Isolation level when Chromium runs under bubblewrap as uid 65534 (root callers).
ISOLATION_BWRAP = ("chromium:bwrap,uid65534,netns,pidns,ipcns,utsns,mountns,nouserns,seccomp,"
                   "no-egress")
#: Isolation level recorded when the user opted out and no namespace could be had.
ISOLATION_NONE = "none"

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
    # The display compositor draws with Skia on the CPU instead of GL on SwiftShader: frames are
    # read from the canvas (or a screenshot), never from the compositor's GL output, and a 2D
    # clip took 0.13-0.16 CPU-s less per render (0.72 -> 0.48 s wall, same frames byte for byte).
    "--disable-gpu-compositing",
    # Screenshot mode: a captured frame must not depend on which paints happened before it in
    # real time (partial raster re-rasters only the damaged part of a tile; compositor-driven
    # animations pick their raster scale by timing). Canvas readback is unaffected by both.
    "--disable-partial-raster",
    "--disable-threaded-animation",
    # WebRTC: no UDP that does not go through a proxy (there is none), no local addresses.
    "--force-webrtc-ip-handling-policy=disable_non_proxied_udp",
    "--webrtc-ip-handling-policy=disable_non_proxied_udp",
    "--disable-breakpad",
    "--disable-crash-reporter",
    "--no-pings",
    "--deny-permission-prompts",
    "--block-new-web-contents",
    # No spare renderer: Chromium keeps a renderer process started ahead for the next page,
    # besides the page the pool prepares itself (`visphy_core.sandbox.prepared`), which the
    # next program takes; the spare held 75 MiB. No omnibox pop-up: each context opens a
    # (hidden) browser window, and recent Chromium gives every window a WebUI renderer for its
    # omnibox pop-up that loads ~400 JavaScript modules: 0.25-0.35 CPU-s per page, spent while
    # the next page is prepared, beside the scoring of the last clip. (The launcher merges this
    # list with Playwright's: `chromium.MERGE_FEATURES_SH`.)
    "--disable-features=SpareRendererForSitePerProcess,WebUIOmniboxPopup,WebUIOmniboxAimPopup",
]

#: V8 options for Playwright's Node.js driver (added to ``$NODE_OPTIONS`` while it starts):
#: every frame passes through it (raw pixels in JSON), and a young generation of 2 MiB
#: semi-spaces instead of V8's default (up to 16 MiB) kept its RSS at 120–130 MiB instead of
#: 150–200 (12 renders of 2D clips, same render times); the old generation keeps V8's limit.
DRIVER_NODE_OPTIONS = "--max-semi-space-size=2"

#: Chromium's stderr lines that mean the page exhausted the JavaScript heap (V8 / Blink OOM).
_OOM_MARKERS = ("javascript OOM", "Reached heap limit", "Last few GCs",
                "Fatal JavaScript out of memory", "Fatal process out of memory",
                "Out of memory: ", "OOM in ")


class BrowserUnavailable(RuntimeError):
    """Chromium or Playwright is missing or would not start."""


class SandboxUnavailable(BrowserUnavailable):
    """The kernel grants no network namespace and the user did not allow unisolated pages."""


# ------------------------------------------------------------------------------ isolation config

_CONFIG: dict = {"memory_mb": None}


def configure(allow_unisolated: bool | None = None, memory_mb: int | None = None) -> None:
    """Settings of the browser sandbox for this process (the run loop calls this from the config:
    ``sandbox.allow_unisolated``). ``None`` leaves a setting as it is. ``memory_mb`` applies to
    pools started afterwards."""
    if allow_unisolated is not None:
        set_allow_unisolated(allow_unisolated)
    if memory_mb is not None:
        if int(memory_mb) < 64:
            raise ValueError(f"memory_mb must be at least 64, not {memory_mb}")
        _CONFIG["memory_mb"] = int(memory_mb)


def browser_isolation_level() -> str:
    """What untrusted pages run under now: `ISOLATION_BWRAP` (root with bubblewrap),
    `ISOLATION_NETNS` (a network namespace only); ``none`` when no namespace is available and
    the user opted out; ``unavailable: <why>`` when pages would be refused. For the manifest."""
    if bwrap_for_chromium()[0] is not None:
        return ISOLATION_BWRAP
    prefix, why = netns_prefix()
    if prefix is not None:
        return ISOLATION_NETNS
    return ISOLATION_NONE if unisolated_allowed() else f"unavailable: {why}"


_NODE_OPTIONS_LOCK = threading.Lock()


@contextmanager
def _driver_node_options() -> Iterator[None]:
    """`DRIVER_NODE_OPTIONS` in ``$NODE_OPTIONS`` while Playwright's driver starts (it copies
    this process's environment): set, then put back as it was. A value the user gave for the
    same option is kept."""
    with _NODE_OPTIONS_LOCK:
        before = os.environ.get("NODE_OPTIONS")
        option = DRIVER_NODE_OPTIONS.split("=", 1)[0]
        if before is not None and option in before:
            yield
            return
        os.environ["NODE_OPTIONS"] = f"{before} {DRIVER_NODE_OPTIONS}" if before \
            else DRIVER_NODE_OPTIONS
        try:
            yield
        finally:
            if before is None:
                os.environ.pop("NODE_OPTIONS", None)
            else:
                os.environ["NODE_OPTIONS"] = before


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


class BrowserPool:
    """Reusable Chromium processes; a fresh browser context per page; restart after a crash.

    ``memory_mb`` caps each page (default: `configure`'s value, else `DEFAULT_MEMORY_MB`): the
    JavaScript heap gets three quarters of it, and a watchdog kills the page's renderer (or the
    GPU process) when its resident memory goes above it. ``untrusted=False`` is for visphy's own
    pages (reference clips): they run without a namespace when none can be had.

    ``readback``: ``"raw"`` (canvas pixels read raw where exact, else PNG) or ``"png"`` (always
    ``toDataURL``). ``prepare_pages``: make each next context and page ahead of use (and close
    finished ones in the background); off, every page is made and closed on demand. Both give
    the same frames; the defaults are the fast path, the others the path they replaced."""

    def __init__(self, size: int = 1, extra_args: list[str] | None = None,
                 restart_every: int = 200, memory_mb: int | None = None,
                 untrusted: bool = True, readback: str = "raw", prepare_pages: bool = True):
        if readback not in READBACK_MODES:
            raise ValueError(f"readback must be one of {READBACK_MODES}, not {readback!r}")
        self.readback = readback
        self.prepare_pages = prepare_pages
        self.size = size
        self.extra_args = extra_args or []
        self.restart_every = restart_every
        self.memory_mb = int(memory_mb or _CONFIG["memory_mb"] or DEFAULT_MEMORY_MB)
        self.untrusted = untrusted
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True,
                                        name="visphy-browser-pool")
        self._thread.start()
        self._playwright = None
        self._browsers: list[ChromiumProcess] = []
        self._uses = 0
        self._next = 0
        self._launches = 0
        self._home: Path | None = None
        self.isolation: str | None = None
        self.restarts = 0
        #: id(browser process) -> the preparation of its next page.
        self._prepared: dict[int, asyncio.Task] = {}
        #: Contexts being closed in the background.
        self._closing: set[asyncio.Task] = set()
        self._restart_due = False

    # ---------------------------------------------------------------- lifecycle

    def _run(self, coro, timeout: float | None = None):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    def _wrapper(self, executable: str) -> Path:
        """A private launcher script: records Chromium's pid, sends its stderr to a file, and
        execs it under bubblewrap as uid 65534 (root callers), else inside a fresh network
        namespace, else (explicit opt-out only) as it is."""
        self.isolation = browser_isolation_level()
        if self.isolation.startswith("unavailable: "):
            if self.untrusted:
                raise SandboxUnavailable(
                    f"cannot isolate the browser: no network namespace "
                    f"({self.isolation.removeprefix('unavailable: ')}); refusing to run "
                    f"model-written pages without one. Run as root or where unprivileged user "
                    f"namespaces are allowed, or opt out explicitly with sandbox.allow_unisolated="
                    f"true (or {ALLOW_UNISOLATED_ENV}=1)")
            self.isolation = ISOLATION_NONE
        if self._home is None:
            self._home = Path(tempfile.mkdtemp(prefix="visphy-chromium-"))
            # also removed when the pool is never closed (the interpreter exits)
            weakref.finalize(self, shutil.rmtree, str(self._home), ignore_errors=True)
        script = self._home / "chromium-launcher"
        bwrap = bwrap_for_chromium()[0]
        if bwrap is not None:
            os.chmod(self._home, 0o711)  # uid 65534 must cross it to reach its profile
            os.chown(self.profile, CHROMIUM_UID, CHROMIUM_UID)
            script.write_text(bwrap_launcher(bwrap, executable, self.profile))
        else:
            prefix = netns_prefix()[0] or []
            cmd = " ".join(sh_quote(a) for a in [*prefix, executable])
            script.write_text("#!/bin/sh\n"
                              'echo $$ > "$VISPHY_CHROMIUM_PIDFILE"\n'
                              f"{MERGE_FEATURES_SH}"
                              f'exec {cmd} "$@" 2>>"$VISPHY_CHROMIUM_STDERR"\n')
        script.chmod(0o700)
        return script

    @property
    def profile(self) -> Path:
        """Chromium's private HOME (and XDG dirs) inside the pool's temp dir."""
        path = self._home / "profile"
        path.mkdir(exist_ok=True)
        return path

    async def _start(self) -> None:
        from playwright.async_api import async_playwright

        executable = find_chromium()
        launcher = self._wrapper(executable)
        if self._playwright is None:
            with _driver_node_options():
                self._playwright = await async_playwright().start()
        heap_mb = max(64, self.memory_mb * 3 // 4)
        while len(self._browsers) < self.size:
            self._launches += 1
            pidfile = self._home / f"browser-{self._launches}.pid"
            stderr = self._home / f"browser-{self._launches}.stderr"
            env = chromium_env(self.profile)
            env["VISPHY_CHROMIUM_PIDFILE"] = str(pidfile)
            env["VISPHY_CHROMIUM_STDERR"] = str(stderr)
            try:
                browser = await asyncio.wait_for(self._playwright.chromium.launch(
                    executable_path=str(launcher), headless=True, timeout=60_000,
                    args=CHROMIUM_ARGS + [f"--js-flags=--max-old-space-size={heap_mb}"]
                    + self.extra_args, env=env), 90)
            except Exception as exc:
                tail = ""
                if stderr.exists():
                    tail = stderr.read_text(errors="replace")[-500:]
                raise BrowserUnavailable(
                    f"Chromium at {executable} failed to start: {exc} {tail}".strip()) from exc
            try:
                pid = int(pidfile.read_text().strip())
            except (OSError, ValueError):
                pid = None
            self._browsers.append(ChromiumProcess(browser, pid, stderr))

    async def _drop_prepared(self) -> None:
        prepared, self._prepared = self._prepared, {}
        for task in prepared.values():
            await discard(task)

    async def _close_browsers(self) -> None:
        await self._drop_prepared()
        closing, self._closing = self._closing, set()
        if closing:
            await asyncio.wait(closing, timeout=10)
        browsers, self._browsers = self._browsers, []
        for proc in browsers:
            try:
                await asyncio.wait_for(proc.browser.close(), 10)
            except Exception:
                pass
            if proc.pid is not None:  # whatever did not go with close()
                kill_all(proc.processes(("renderer", "gpu-process", "utility", "zygote", "browser"))
                      + [proc.pid])
            for path in (proc.stderr, proc.stderr.with_suffix(".pid")):
                try:
                    path.unlink()
                except OSError:
                    pass

    async def _shut_down(self) -> None:
        """Close the browsers, then stop Playwright's driver (waiting at most 10 s)."""
        await self._close_browsers()
        if self._playwright is not None:
            try:
                await asyncio.wait_for(self._playwright.stop(), 10)
            except Exception:
                pass
            self._playwright = None

    async def _restart(self) -> None:
        await self._shut_down()
        self.restarts += 1
        await self._start()

    def close(self) -> None:
        if self._thread.is_alive():
            try:
                self._run(self._shut_down(), timeout=30)
            finally:
                self._loop.call_soon_threadsafe(self._loop.stop)
                self._thread.join(timeout=5)
        if self._home is not None:
            shutil.rmtree(self._home, ignore_errors=True)
            self._home = None

    def __enter__(self) -> "BrowserPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- rendering

    def render_page(self, html: str, assets: Mapping[str, Asset], times_ms: list[float], *,
                    width: int, height: int, timeout_s: float, seed: int = 0,
                    tick_ms: float = 1000 / 60, capture: str = "canvas",
                    inject_fault: str | None = None, preload: Sequence[str] = ()
                    ) -> PageCapture:
        """Load ``html`` at the fake origin and capture a frame at each virtual time.

        ``assets`` maps URL paths (``vendor/...``) to files or to their content (bytes/str).
        ``capture``: ``"canvas"`` reads back the main canvas; ``"screenshot"`` screenshots the
        viewport (0, 0, width, height) after seeking document animations to the virtual time.
        ``preload``: paths of ``assets`` (the engine's libraries) run at the start of every
        document of the page, after the virtual clock and before the page's own scripts, as the
        first scripts of its head would be (prepared pages have them compiled ahead).
        ``inject_fault`` (tests only): ``"crash"`` crashes the renderer after the first frame;
        ``"real-webrtc"`` leaves the page the browser's own ``RTCPeerConnection`` (to show that
        the network namespace and Chromium's WebRTC policy hold on their own).
        Raises `SandboxUnavailable` when the page cannot be isolated (and no opt-out is set).
        """
        if capture not in CAPTURE_MODES:
            raise ValueError(f"capture must be one of {CAPTURE_MODES}, not {capture!r}")
        return self._run(self._render(html, assets, times_ms, width, height,
                                      timeout_s, seed, tick_ms, capture, inject_fault,
                                      tuple(preload)))

    async def _browser_for_page(self) -> ChromiumProcess:
        """The browser the next page runs in (started or restarted as needed)."""
        if self._restart_due or self._uses >= self.restart_every:
            self._restart_due = False
            await self._restart()
            self._uses = 0
        elif not self._browsers:
            await self._start()
        proc = self._browsers[self._next % len(self._browsers)]
        self._next += 1
        if not proc.browser.is_connected():
            await self._restart()
            proc = self._browsers[0]
        self._uses += 1
        return proc

    async def _page_for(self, proc: ChromiumProcess, width: int, height: int, init: PageInit,
                        assets: Mapping[str, Asset]) -> PreparedPage:
        """The page prepared for ``proc`` when it fits, else a new one (made now, no warm-up)."""
        task = self._prepared.pop(id(proc), None)
        if task is not None:
            try:
                prepared = await task
            except Exception:
                prepared = None
            if prepared is not None and prepared.usable(proc, (width, height), init):
                prepared.ahead = True
                return prepared
            if prepared is not None:
                self._close_later(prepared.context)
        return await open_page(proc, width, height, init, assets=assets,
                               cap_factory=PageCapture)

    def _prepare_next(self, proc: ChromiumProcess, width: int, height: int,
                      init: PageInit, assets: Mapping[str, Asset]) -> None:
        """Start preparing ``proc``'s next page (same size and init, the init compiled)."""
        if not self.prepare_pages or self._restart_due or id(proc) in self._prepared:
            return
        if proc not in self._browsers or not proc.browser.is_connected():
            return
        self._prepared[id(proc)] = asyncio.ensure_future(asyncio.wait_for(
            open_page(proc, width, height, init, warm=True, assets=assets,
                      cap_factory=PageCapture),
            60))

    def _close_later(self, context) -> None:
        """Close a finished context in the background; a context that will not close gets the
        pool restarted before the next page."""
        async def close():
            try:
                await asyncio.wait_for(context.close(), 5)
            except Exception:
                self._restart_due = True

        task = asyncio.ensure_future(close())
        self._closing.add(task)
        task.add_done_callback(self._closing.discard)

    async def _render(self, html, assets, times_ms, width, height, timeout_s, seed, tick_ms,
                      capture="canvas", inject_fault=None, preload=()):
        from playwright.async_api import TimeoutError as PlaywrightTimeout

        init = page_init(assets, preload, tick_ms=tick_ms, seed=seed, capture=capture,
                         real_webrtc=inject_fault == "real-webrtc")
        proc = await self._browser_for_page()
        browser = proc.browser
        # The page's clock starts once a browser is up (starting one is ours, not the page's).
        start = time.perf_counter()
        deadline = start + timeout_s
        cap = PageCapture(isolation=self.isolation)
        timings = cap.timings
        mark = [start]

        def lap(phase: str) -> None:
            now = time.perf_counter()
            timings[phase] = timings.get(phase, 0.0) + now - mark[0]
            mark[0] = now

        context = None
        crashed: list[bool] = []
        killed: list[str] = []
        stderr_at = proc.stderr_size()
        if stderr_at > (32 << 20):  # keep the log file small; only new lines matter
            try:
                proc.stderr.write_bytes(b"")
            except OSError:
                pass
            stderr_at = 0
        cap_bytes = self.memory_mb << 20
        watchdog = asyncio.ensure_future(self._watch(proc, cap_bytes, killed))

        def left() -> float:
            return max(0.05, deadline - time.perf_counter())

        try:
            prepared = await asyncio.wait_for(
                self._page_for(proc, width, height, init, assets), left())
            context, page, crashed = prepared.context, prepared.page, prepared.crashed
            await load_program(prepared, html, assets, cap, left, lap)
            await capture_frames(context, page, cap, times_ms, width, height, capture,
                                 self.readback, inject_fault, crashed, deadline, left, lap)
            state = await asyncio.wait_for(page.evaluate(
                "() => [window.__visphy.errors(), window.__visphy.logs(),"
                " window.__visphy.attempts()]"), left())
            lap("state")
            if isinstance(state, list) and len(state) == 3:
                cap.errors.extend(str(e)[:2000] for e in list(state[0])[:200])
                cap.console.extend(str(e)[:600] for e in list(state[1])[:600])
                for entry in list(state[2])[:200]:
                    cap.block(str(entry)[:300])
        except (asyncio.TimeoutError, PlaywrightTimeout):
            if not crashed and not killed:
                cap.timed_out = True
        except Exception as exc:  # a crash of the renderer or the browser, or a page failure
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if crashed or killed or "crash" in msg.lower():
                crashed.append(True)  # classified below: the program's memory, or ours
            elif "has been closed" in msg or not browser.is_connected():
                cap.infra_error = f"browser failure: {msg[:500]}"
            elif not cap.navigations:  # (a page that navigated away is classified as such)
                cap.errors.append(f"page failure: {msg[:500]}")
        finally:
            watchdog.cancel()
            await self._end_page(proc, browser, context, cap, bool(crashed or killed), stderr_at,
                                 killed, width, height, init, assets)
            lap("close")
        cap.wall_s = time.perf_counter() - start
        return cap.detached()

    async def _end_page(self, proc: ChromiumProcess, browser, context, cap: PageCapture,
                        died: bool, stderr_at: int, killed: list[str], width, height,
                        init: PageInit, assets) -> None:
        """After a page: classify a crash, close (or hand back) its context, and restart the
        pool or prepare the browser's next page."""
        if cap.timed_out:
            # A renderer stuck in a loop may not let its context close: end it first (and
            # the page prepared next to it, which went with it).
            await self._drop_prepared()
            kill_all(proc.processes(("renderer",)))
        if died and not cap.infra_error:
            await asyncio.sleep(0.05)  # let the renderer's last words reach the log
            self._classify_crash(cap, proc, stderr_at, killed)
        restart = False
        clean = not (cap.timed_out or died or cap.infra_error)
        if context is not None and clean and self.prepare_pages:
            self._close_later(context)
        elif context is not None:
            try:
                await asyncio.wait_for(context.close(), 3)
            except Exception:
                # e.g. an endless loop in an unload handler: end the renderer, try again
                await self._drop_prepared()
                kill_all(proc.processes(("renderer",)))
                try:
                    await asyncio.wait_for(context.close(), 3)
                except Exception:
                    restart = True
        # A crashed renderer takes only its page down; restart when the browser went too.
        if (cap.infra_error or cap.resource_limit) and not browser.is_connected():
            restart = True
        if restart:
            await self._restart()
        else:
            self._prepare_next(proc, width, height, init, assets)

    def _classify_crash(self, cap: PageCapture, proc: ChromiumProcess, stderr_at: int,
                        killed: list[str]) -> None:
        """A renderer that died: the program's memory (our kill, or V8 out of heap), else ours."""
        cap.timed_out = False
        if killed:
            cap.resource_limit = killed[0]
            return
        tail = proc.stderr_since(stderr_at)
        if any(marker in tail for marker in _OOM_MARKERS):
            cap.resource_limit = (f"memory limit: the page exhausted its JavaScript heap "
                                  f"({max(64, self.memory_mb * 3 // 4)} MB)")
        else:
            cap.infra_error = "browser failure: the renderer crashed"

    async def _watch(self, proc: ChromiumProcess, cap_bytes: int, killed: list[str]) -> None:
        """Kill a renderer (or the GPU process) whose resident memory goes above the cap."""
        pids: list[int] = []
        n = 0
        try:
            while True:
                if n % 5 == 0 or not pids:  # new processes appear rarely; memory grows fast
                    pids = await asyncio.to_thread(proc.processes, ("renderer", "gpu-process"))
                n += 1
                for pid in pids:
                    rss = rss_bytes(pid)
                    if rss > cap_bytes:
                        kill_all([pid])
                        kind = {"gpu-process": "GPU"}.get(proc.kinds.get(pid, ""), "renderer")
                        killed.append(f"memory limit: the page's {kind} process used "
                                      f"{rss >> 20} MB, above the cap of {cap_bytes >> 20} MB; "
                                      f"it was stopped")
                await asyncio.sleep(WATCH_INTERVAL_S)
        except asyncio.CancelledError:
            return
