"""The rating server: a loopback-only ``ThreadingHTTPServer`` with four endpoints.

* ``GET /``: the page (``page.html``, static: nothing in it depends on the runs);
* ``GET /api/state``: the rater, the number of items, how many are rated and the queue of
  unrated items in the rater's order, each ``{item, position, reference, generated}``: an opaque
  id, its place in the order and two video URLs made of that id alone;
* ``GET /video/<item>/reference.mp4`` and ``…/generated.mp4``: the clips, with range requests;
* ``POST /api/rate`` ``{item, rating, comment}``: one rating, appended to the item's run.

Checks, each answered ``400`` with a one-line JSON error: a ``Host`` header other than the
server's own address (a page on another site reaching the server through DNS rebinding), a POST
whose ``Origin`` is not the page's, a body that is not a JSON object, an unknown item id, a rating
that is not an integer 1–5, a comment that is not text, an item the rater already rated.
"""

from __future__ import annotations

import ipaddress
import json
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import urlsplit

from visphy_core.human.items import RatingItem, rater_order
from visphy_core.human.media import PlayableCopies, byte_range
from visphy_core.human.store import RATINGS, RatingStore, check_rater
from visphy_core.infra.errors import UserError

PAGE = Path(__file__).with_name("page.html")
MAX_BODY = 16 * 1024
CHUNK = 256 * 1024
VIDEO_KINDS = ("reference", "generated")


class BadRequest(ValueError):
    """A request the server refuses (its message is the JSON error the page receives)."""


class RatingSession:
    """One rater's session over a fixed set of items: the order, what is rated, the writes."""

    def __init__(self, items: list[RatingItem], rater: str, store: RatingStore | None = None):
        self.rater = check_rater(rater)
        self.order = rater_order(items, self.rater)
        self.by_id = {i.item: i for i in items}
        self.store = store or RatingStore(items)
        self.rated = self.store.rated_by(self.rater)
        self.written = 0
        self._lock = threading.Lock()

    def state(self) -> dict:
        with self._lock:
            queue = [{"item": it.item, "position": k + 1,
                      "reference": f"/video/{it.item}/reference.mp4",
                      "generated": f"/video/{it.item}/generated.mp4"}
                     for k, it in enumerate(self.order) if it.item not in self.rated]
            return {"rater": self.rater, "total": len(self.order), "rated": len(self.rated),
                    "queue": queue}

    def rate(self, payload: object) -> dict:
        """Validate one POSTed rating and append it (`BadRequest` when it is refused)."""
        if not isinstance(payload, dict):
            raise BadRequest("the body must be a JSON object {item, rating, comment}")
        item = self.by_id.get(payload.get("item")) if isinstance(payload.get("item"), str) \
            else None
        if item is None:
            raise BadRequest("unknown item")
        rating = payload.get("rating")
        if isinstance(rating, bool) or not isinstance(rating, int) or rating not in RATINGS:
            raise BadRequest("rating must be an integer from 1 to 5")
        comment = payload.get("comment")
        if comment is not None and not isinstance(comment, str):
            raise BadRequest("comment must be text or null")
        with self._lock:
            if item.item in self.rated:
                raise BadRequest("this item is already rated")
            self.store.append(item, self.rater, rating, comment)
            self.rated.add(item.item)
            self.written += 1
            return {"ok": True, "rated": len(self.rated), "total": len(self.order)}

    def video(self, item_id: str, kind: str) -> Path | None:
        item = self.by_id.get(item_id)
        if item is None or kind not in VIDEO_KINDS:
            return None
        return item.reference if kind == "reference" else item.generated


def loopback_address(host: str) -> str:
    """``host`` as a loopback IP address (`UserError` for anything else: ratings are local)."""
    if host == "localhost":
        return "127.0.0.1"
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        raise UserError(f"--host {host!r} is not an IP address; the rating server binds "
                        "loopback only (127.0.0.1, ::1 or localhost)") from None
    if not ip.is_loopback:
        raise UserError(f"--host {host}: the rating server binds loopback only (127.0.0.1, ::1 "
                        "or localhost)")
    return str(ip)


class RatingServer(ThreadingHTTPServer):
    """The HTTP server of one `RatingSession` (``port=0``: any free port; see ``url``)."""

    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, session: RatingSession, copies: PlayableCopies, host: str = "127.0.0.1",
                 port: int = 0, quiet: bool = True):
        address = loopback_address(host)
        self.address_family = socket.AF_INET6 if ":" in address else socket.AF_INET
        super().__init__((address, port), RatingHandler)
        self.session, self.copies, self.quiet = session, copies, quiet
        self.port = self.server_address[1]
        shown = f"[{address}]" if ":" in address else address
        self.url = f"http://{shown}:{self.port}/"
        self.hosts = {f"{shown}:{self.port}", f"localhost:{self.port}"}


class RatingHandler(BaseHTTPRequestHandler):
    server: RatingServer
    server_version = "visphy-rate"
    sys_version = ""

    # --------------------------------------------------------------------------- helpers
    def log_message(self, format: str, *args) -> None:  # noqa: A002 - the base's signature
        if not self.server.quiet:
            super().log_message(format, *args)

    def _send(self, status: int, body: bytes, content_type: str,
              headers: dict[str, str] | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        for key, value in (headers or {}).items():
            self.send_header(key, value)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, obj: dict) -> None:
        self._send(status, json.dumps(obj).encode(), "application/json")

    def _error(self, status: int, message: str) -> None:
        self._json(status, {"ok": False, "error": message})

    def _host_ok(self) -> bool:
        if self.headers.get("Host") in self.server.hosts:
            return True
        self._error(400, "unexpected Host header")
        return False

    # --------------------------------------------------------------------------- GET
    def do_GET(self) -> None:  # noqa: N802 - http.server's naming
        if not self._host_ok():
            return
        path = urlsplit(self.path).path
        if path in ("/", "/index.html"):
            self._send(200, PAGE.read_bytes(), "text/html; charset=utf-8")
        elif path == "/api/state":
            self._json(200, self.server.session.state())
        elif path.startswith("/video/"):
            self._video(path)
        else:
            self._error(404, "not found")

    def _video(self, path: str) -> None:
        parts = path.split("/")
        kind = parts[3].removesuffix(".mp4") if len(parts) == 4 and \
            parts[3].endswith(".mp4") else ""
        clip = self.server.session.video(parts[2], kind) if kind else None
        if clip is None:
            self._error(404, "not found")
            return
        data = self.server.copies.get(clip)
        size = data.stat().st_size
        try:
            span = byte_range(self.headers.get("Range"), size)
        except ValueError:
            self._send(416, b"", "video/mp4", {"Content-Range": f"bytes */{size}"})
            return
        start, end = span or (0, size - 1)
        self.send_response(206 if span else 200)
        self.send_header("Content-Type", "video/mp4")
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Content-Length", str(end - start + 1))
        self.send_header("Cache-Control", "no-store")
        if span:
            self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.end_headers()
        try:
            with open(data, "rb") as fh:
                fh.seek(start)
                left = end - start + 1
                while left > 0:
                    chunk = fh.read(min(CHUNK, left))
                    if not chunk:
                        break
                    self.wfile.write(chunk)
                    left -= len(chunk)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the browser cancelled the request (it does when it seeks)

    # --------------------------------------------------------------------------- POST
    def do_POST(self) -> None:  # noqa: N802
        if not self._host_ok():
            return
        if urlsplit(self.path).path != "/api/rate":
            self._error(404, "not found")
            return
        if self.headers.get("Origin") != f"http://{self.headers.get('Host')}":
            self._error(400, "ratings are accepted from the rating page only")
            return
        if not (self.headers.get("Content-Type") or "").startswith("application/json"):
            self._error(400, "the body must be application/json")
            return
        try:
            length = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            length = -1
        if not 0 < length <= MAX_BODY:
            self._error(400, f"the body must be 1 to {MAX_BODY} bytes")
            return
        try:
            payload = json.loads(self.rfile.read(length).decode("utf-8"))
            self._json(200, self.server.session.rate(payload))
        except (ValueError, UnicodeDecodeError) as exc:  # BadRequest is a ValueError
            message = str(exc) if isinstance(exc, BadRequest) else "the body is not JSON"
            self._error(400, message)
        except OSError as exc:  # the run directory is not writable
            self._error(500, f"the rating could not be saved: {exc.strerror or exc}")
