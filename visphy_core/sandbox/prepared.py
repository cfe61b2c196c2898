"""Pages prepared ahead of use: a fresh browser context and page per program, made before the
program is known, so the next render does not wait for them.

Why: creating a context and its page starts a new renderer process, and compiling the engine's
libraries is most of a page's load; both cost as much as the whole frame
capture of a 2D clip. A prepared page pays them while the previous program's results are being
handled. Isolation is unchanged: each program still gets a context of its own, used by no other
program, and what was prepared in it is visphy's, not a program's.

What runs before a page's own scripts is the page's *init*: the virtual clock (with its
configuration), then the engine's preloaded libraries, each an init script of the context, run
at the start of every document (`PageInit`). A prepared page registers them and loads one blank
document, which runs them once: the renderer process then holds their compiled code (V8 caches a
script's code by its source and origin), and the program's document runs them again from that
cache, in a new window with nothing of the blank document's globals. Its history holds the same
entries as with a page made on demand.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Mapping

from visphy_core.sandbox.routing import (
    Asset,
    PageSlot,
    close_quietly,
    make_router,
    make_ws_router,
)

@dataclass(frozen=True)
class PageInit:
    """The scripts run at the start of every document of a page, in order, before any of its
    own: the virtual clock with its configuration, then the preloaded libraries' sources."""

    scripts: tuple[str, ...] = ()


@dataclass
class PreparedPage:
    """A fresh context with one blank page, its request handlers bound to ``slot``."""

    proc: object  # the ChromiumProcess it lives in
    context: object
    page: object
    slot: PageSlot
    size: tuple[int, int]
    init: PageInit = PageInit()
    crashed: list = field(default_factory=list)
    #: Set when a program takes it: it was made ahead of that program.
    ahead: bool = False

    def usable(self, proc, size: tuple[int, int], init: PageInit) -> bool:
        """Whether this page can take a program for ``proc`` at ``size`` with ``init`` now."""
        try:
            alive = not self.page.is_closed() and self.proc.browser.is_connected()
        except Exception:
            alive = False
        return (alive and not self.crashed and self.proc is proc and self.size == size
                and self.init == init)


async def open_page(proc, width: int, height: int, init: PageInit = PageInit(), *,
                    warm: bool = False, assets: Mapping[str, Asset] | None = None,
                    cap_factory=None) -> PreparedPage:
    """A new context (viewport ``width``×``height``, no service workers, no downloads, ``init``
    run in each document) with one blank page whose requests go through a `PageSlot`;
    ``warm``: load one blank document first, which compiles the init scripts in the page's
    renderer (their code is then taken from V8's cache when the program's document runs them)."""
    context = await proc.browser.new_context(
        viewport={"width": width, "height": height}, device_scale_factor=1,
        service_workers="block", accept_downloads=False)
    try:
        slot = PageSlot(assets=assets or {}, cap=cap_factory() if cap_factory else None)
        await context.route("**/*", make_router(slot))
        await context.route_web_socket("**/*", make_ws_router(slot))
        for script in init.scripts:
            await context.add_init_script(script)
        page = await context.new_page()
        prepared = PreparedPage(proc, context, page, slot, (width, height), init)
        page.on("crash", lambda _page: prepared.crashed.append(True))
        if warm and init.scripts:
            await page.goto("about:blank")
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
