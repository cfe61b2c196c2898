"""What a page may load, and what it tried: the fake origin's request handlers.

A page is served from a fixed fake origin (``https://visphy.invalid``): its document and the
vendored files are fulfilled by request interception, without sockets; every other request (any
host, WebSocket, EventSource, beacons, navigations away, pop-ups) is refused and logged in the
page's capture. A `PageSlot` holds what the handlers serve and where they log; a page prepared
ahead of use (`visphy_core.sandbox.prepared`) gets its program's slot contents just before it
navigates.
"""

from __future__ import annotations

import asyncio
import mimetypes
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Union
from urllib.parse import urlparse

ORIGIN_HOST = "visphy.invalid"
ORIGIN = f"https://{ORIGIN_HOST}"

#: What the fake origin serves for a path: a file, or the content itself (generated wrappers).
Asset = Union[Path, bytes, str]


@dataclass
class PageSlot:
    """What one page is served (its document and assets) and the capture its attempts go to."""

    html: str = ""
    assets: Mapping[str, Asset] = field(default_factory=dict)
    cap: Any = None
    #: URLs of the main document served so far (it is served once; then the page is leaving).
    served: list = field(default_factory=list)

    def load(self, html: str, assets: Mapping[str, Asset], cap) -> None:
        self.html, self.assets, self.cap, self.served = html, assets, cap, []


_BODIES: dict = {}


def _vendored(path: Path) -> list:
    """A vendored file's cache entry, [bytes, text or None]: read once per process (files never
    change under a lock file's folder), kept by path, size and modification time; its UTF-8
    text is decoded the first time a page runs it as an init script."""
    st = path.stat()
    key = (str(path), st.st_size, st.st_mtime_ns)
    entry = _BODIES.get(key)
    if entry is None:
        if len(_BODIES) > 256:
            _BODIES.clear()
        entry = _BODIES[key] = [path.read_bytes(), None]
    return entry


def _asset_body(item: Asset) -> bytes:
    """The bytes of an asset (a vendored file's from the process cache)."""
    if not isinstance(item, Path):
        return item.encode() if isinstance(item, str) else bytes(item)
    return _vendored(item)[0]


def asset_text(item: Asset) -> str:
    """An asset as UTF-8 text (a library run as an init script); a vendored file's is decoded
    once per process."""
    if isinstance(item, str):
        return item
    if not isinstance(item, Path):
        return bytes(item).decode("utf-8")
    entry = _vendored(item)
    if entry[1] is None:
        entry[1] = entry[0].decode("utf-8")
    return entry[1]


def make_router(slot: PageSlot):
    """The request handler of a context: the slot's document once, its assets, nothing else."""

    async def handle(route):
        request = route.request
        url = request.url
        cap = slot.cap
        try:
            navigation = request.is_navigation_request()
            main = navigation and request.frame.parent_frame is None
        except Exception:
            navigation = main = False
        parsed = urlparse(url)
        if main and slot.served:
            # The main document was served once: anything else is the page leaving.
            cap.navigations.append(f"navigation {url[:300]}")
            cap.block(f"navigation {url[:300]}")
            await route.abort("blockedbyclient")
            return
        if parsed.hostname == ORIGIN_HOST and parsed.scheme == "https":
            path = parsed.path.lstrip("/")
            if path == "index.html" and main:
                slot.served.append(url)
                await route.fulfill(status=200, body=slot.html.encode(),
                                    content_type="text/html; charset=utf-8")
                return
            if path in slot.assets:
                name = Path(path).name
                ctype = mimetypes.guess_type(name)[0] or "application/octet-stream"
                if Path(name).suffix in (".js", ".mjs", ".cjs"):
                    ctype = "text/javascript"
                await route.fulfill(status=200, body=_asset_body(slot.assets[path]),
                                    content_type=ctype)
                return
            cap.block(f"{request.resource_type} {url[:300]}")
            await route.fulfill(status=404, body=b"not vendored", content_type="text/plain")
            return
        cap.block(f"{request.resource_type} {url[:300]}")
        await route.abort("blockedbyclient")

    return handle


def make_ws_router(slot: PageSlot):
    """WebSockets are refused and logged."""

    def handle(ws):
        slot.cap.block(f"websocket {ws.url[:300]}")
        asyncio.ensure_future(close_quietly(ws, code=1008, reason="blocked by visphy"))

    return handle


def on_popup(popup, cap) -> None:
    cap.navigations.append(f"popup {popup.url[:300]}")
    cap.block(f"popup {popup.url[:300]}")
    asyncio.ensure_future(close_quietly(popup))


def on_console(msg, cap) -> None:
    """Chromium's own console messages about refused loads (``file://`` and the like), which
    no request handler sees."""
    try:
        if msg.type != "error":
            return
        text = msg.text
    except Exception:
        return
    m = re.search(r"Not allowed to load local resource: (\S+)", text)
    if m:
        cap.block(f"file {m.group(1)[:300]}")


async def close_quietly(obj, **kwargs) -> None:
    try:
        await asyncio.wait_for(obj.close(**kwargs), 5)
    except Exception:
        pass
