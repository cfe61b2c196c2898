"""Pages prepared ahead of use: a fresh browser context and page per program, made before the
program is known, so the next render does not wait for them.

Why: creating a context and its page starts a new renderer process, and parsing the engine's
libraries (three.js, p5...) is most of a page's load; both cost as much as the whole frame
capture of a 2D clip. A prepared page pays them while the previous program's results are being
handled. Isolation is unchanged: each program still gets a context of its own, used by no other
program, and what was prepared in it is visphy's, not a program's. The libraries are warmed up
by loading them as scripts into the page's initial blank document, whose origin is opaque: the
program's document (at the fake origin) gets a new window, with nothing of the blank document's
globals, and its history holds the same entries as with a page made on demand. What carries over
is the renderer process' compiled code for those library files (V8 caches a script's code by its
source and URL).
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Mapping, Sequence

from visphy_core.sandbox.routing import (
    ORIGIN,
    Asset,
    PageSlot,
    close_quietly,
    make_router,
    make_ws_router,
)

#: Loads the given script URLs into the current (blank) document and waits for each to load or
#: fail; runs in the page before any program, with no virtual clock installed.
WARM_SCRIPTS_JS = """urls => Promise.all(urls.map(url => new Promise(resolve => {
  const s = document.createElement('script');
  s.src = url;
  s.onload = s.onerror = () => resolve();
  (document.head || document.documentElement).appendChild(s);
})))"""


@dataclass
class PreparedPage:
    """A fresh context with one blank page, its request handlers bound to ``slot``."""

    proc: object  # the ChromiumProcess it lives in
    context: object
    page: object
    slot: PageSlot
    size: tuple[int, int]
    crashed: list = field(default_factory=list)
    #: Set when a program takes it: it was made ahead of that program.
    ahead: bool = False

    def usable(self, proc, size: tuple[int, int]) -> bool:
        """Whether this page can take a program for ``proc`` at ``size`` now."""
        try:
            alive = not self.page.is_closed() and self.proc.browser.is_connected()
        except Exception:
            alive = False
        return alive and not self.crashed and self.proc is proc and self.size == size


async def open_page(proc, width: int, height: int, warm: Sequence[str] = (),
                    assets: Mapping[str, Asset] | None = None, cap_factory=None
                    ) -> PreparedPage:
    """A new context (viewport ``width``×``height``, no service workers, no downloads) with one
    blank page whose requests go through a `PageSlot`; ``warm``: paths of ``assets`` to load
    into the blank document first (their code is then compiled when the program loads them)."""
    context = await proc.browser.new_context(
        viewport={"width": width, "height": height}, device_scale_factor=1,
        service_workers="block", accept_downloads=False)
    try:
        slot = PageSlot(assets=assets or {}, cap=cap_factory() if cap_factory else None)
        await context.route("**/*", make_router(slot))
        await context.route_web_socket("**/*", make_ws_router(slot))
        page = await context.new_page()
        prepared = PreparedPage(proc, context, page, slot, (width, height))
        page.on("crash", lambda _page: prepared.crashed.append(True))
        paths = [p.lstrip("/") for p in warm if p.lstrip("/") in slot.assets]
        if paths:
            await page.evaluate(WARM_SCRIPTS_JS, [f"{ORIGIN}/{p}" for p in paths])
    except BaseException:
        await close_quietly(context)
        raise
    return prepared


async def discard(task: "asyncio.Future[PreparedPage] | None") -> None:
    """Close what a preparation made (or stop it while it runs)."""
    if task is None:
        return
    if not task.done():
        task.cancel()
    try:
        prepared = await task
    except BaseException:
        return
    await close_quietly(prepared.context)
