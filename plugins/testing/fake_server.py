"""A scriptable fake provider server on loopback, speaking real HTTP.

Subclasses (`fake_openai.py`, `fake_anthropic.py`, `fake_gemini.py`) implement one provider's
wire format; this base records every request (method, path, query, headers, body) and plays a
script of behaviours, so a test drives the real SDK against it and then inspects exactly what
the SDK sent:

* ``ok(text, usage)``: a normal reply;
* ``status(code, headers, message)``: an HTTP error in the provider's error format
  (429 with ``Retry-After``, 500, 401, ...);
* ``malformed()``: 200 with a body that is not JSON;
* ``truncated(text)``: the reply cut by the token limit (the provider's "length" reason);
* ``refusal(text)``: the model refuses (the provider's refusal signal);
* ``empty()``: a well-formed reply with no text;
* ``delay(seconds, then)``: wait, then behave as ``then`` (for client timeouts);
* ``drop()``: close the connection without an answer.

The script is consumed in order; when it runs out, ``default`` (a function of the request)
decides, by default ``ok`` with `default_text`. Use as a context manager::

    with FakeOpenAIServer() as server:
        server.script = [status(429, {"Retry-After": "0"}), ok("hi")]
        ... base_url=server.url ...
    server.requests  # what arrived
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Callable
from urllib.parse import parse_qs, urlsplit


@dataclass
class Behaviour:
    kind: str
    text: str = ""
    status: int = 200
    headers: dict[str, str] = field(default_factory=dict)
    usage: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    then: "Behaviour | None" = None


def ok(text: str, usage: dict[str, int] | None = None) -> Behaviour:
    return Behaviour("ok", text=text, usage=usage or {})


def status(code: int, headers: dict[str, str] | None = None, message: str = "") -> Behaviour:
    return Behaviour("status", status=code, headers=headers or {},
                     text=message or f"fake error {code}")


def malformed() -> Behaviour:
    return Behaviour("malformed")


def truncated(text: str) -> Behaviour:
    return Behaviour("truncated", text=text)


def refusal(text: str = "I can't help with that.") -> Behaviour:
    return Behaviour("refusal", text=text)


def empty() -> Behaviour:
    return Behaviour("empty")


def delay(seconds: float, then: Behaviour) -> Behaviour:
    return Behaviour("delay", seconds=seconds, then=then)


def drop() -> Behaviour:
    return Behaviour("drop")


@dataclass
class Recorded:
    """One request as it arrived."""

    method: str
    path: str
    query: dict[str, list[str]]
    headers: dict[str, str]      # lower-case names
    body: bytes
    time: float

    @property
    def json(self) -> Any:
        try:
            return json.loads(self.body or b"null")
        except ValueError:
            return None

    @property
    def raw_url(self) -> str:
        return self.path + ("?" + "&".join(f"{k}={v}" for k, vs in self.query.items()
                                           for v in vs) if self.query else "")


DEFAULT_USAGE = {"input_tokens": 1200, "output_tokens": 800}


class FakeProviderServer:
    """Base: HTTP plumbing, recording and the script. Subclasses define the wire format."""

    #: Header names whose values are the API key (checked by tests: never in URLs or logs).
    name = "fake"

    def __init__(self, default: Callable[[Recorded], Behaviour] | None = None):
        self.script: list[Behaviour] = []
        self.default = default or (lambda req: ok(self.default_text(req), dict(DEFAULT_USAGE)))
        self.requests: list[Recorded] = []
        self._lock = threading.Lock()
        self._httpd: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ wire format (override)
    def default_text(self, req: Recorded) -> str:
        return "fake reply"

    def handles(self, req: Recorded) -> bool:
        """Whether the request is one this provider's API serves."""
        return True

    def ok_body(self, req: Recorded, text: str, usage: dict[str, int]) -> dict:
        raise NotImplementedError

    def truncated_body(self, req: Recorded, text: str) -> dict:
        raise NotImplementedError

    def refusal_body(self, req: Recorded, text: str) -> dict:
        raise NotImplementedError

    def empty_body(self, req: Recorded) -> dict:
        raise NotImplementedError

    def error_body(self, code: int, message: str) -> dict:
        return {"error": {"code": code, "message": message, "type": "fake_error"}}

    def other(self, req: Recorded) -> tuple[int, dict, dict[str, str]] | None:
        """Requests outside the scripted one (e.g. a video download): (status, body, headers)."""
        return None

    # ------------------------------------------------------------------ lifecycle
    @property
    def url(self) -> str:
        assert self._httpd is not None, "server not started"
        host, port = self._httpd.server_address[:2]
        return f"http://{host}:{port}"

    def start(self) -> "FakeProviderServer":
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: Any) -> None:  # quiet
                pass

            def _handle(self) -> None:
                length = int(self.headers.get("content-length") or 0)
                body = self.rfile.read(length) if length else b""
                parts = urlsplit(self.path)
                req = Recorded(self.command, parts.path, parse_qs(parts.query),
                               {k.lower(): v for k, v in self.headers.items()}, body,
                               time.time())
                server._serve(self, req)

            do_GET = do_POST = do_PUT = do_DELETE = _handle

        self._httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._httpd.daemon_threads = True
        self._thread = threading.Thread(target=self._httpd.serve_forever, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._httpd = None

    def __enter__(self) -> "FakeProviderServer":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    # ------------------------------------------------------------------ serving
    def count(self, predicate: Callable[[Recorded], bool] | None = None) -> int:
        with self._lock:
            return sum(1 for r in self.requests if predicate is None or predicate(r))

    def _next(self, req: Recorded) -> Behaviour:
        with self._lock:
            self.requests.append(req)
            if self.script:
                return self.script.pop(0)
        return self.default(req)

    def _send(self, handler: BaseHTTPRequestHandler, code: int, payload: bytes,
              headers: dict[str, str] | None = None, content_type: str = "application/json"
              ) -> None:
        try:
            handler.send_response(code)
            handler.send_header("content-type", content_type)
            handler.send_header("content-length", str(len(payload)))
            for k, v in (headers or {}).items():
                handler.send_header(k, v)
            handler.end_headers()
            handler.wfile.write(payload)
            handler.wfile.flush()
        except ConnectionError:
            # The client hung up first (a ``delay`` past its timeout): nobody reads this
            # reply. Without this the server thread's traceback lands on the test's stderr.
            handler.close_connection = True

    def _serve(self, handler: BaseHTTPRequestHandler, req: Recorded) -> None:
        other = None if self.handles(req) else self.other(req)
        if other is not None:
            with self._lock:
                self.requests.append(req)
            code, body, headers = other
            payload = body if isinstance(body, bytes) else json.dumps(body).encode()
            ctype = headers.pop("content-type", "application/json") if headers else \
                "application/json"
            self._send(handler, code, payload, headers, ctype)
            return
        if not self.handles(req):
            self._send(handler, 404, json.dumps(self.error_body(404, f"no route {req.path}"))
                       .encode())
            return
        behaviour = self._next(req)
        while behaviour.kind == "delay":
            time.sleep(behaviour.seconds)
            behaviour = behaviour.then or ok(self.default_text(req))
        kind = behaviour.kind
        if kind == "drop":
            handler.close_connection = True
            try:
                handler.connection.shutdown(2)
            except OSError:
                pass
            return
        if kind == "malformed":
            self._send(handler, 200, b'{"id": "broken", "choices": [ {"message": ')
            return
        if kind == "status":
            self._send(handler, behaviour.status,
                       json.dumps(self.error_body(behaviour.status, behaviour.text)).encode(),
                       behaviour.headers)
            return
        body = {"ok": lambda: self.ok_body(req, behaviour.text,
                                           behaviour.usage or dict(DEFAULT_USAGE)),
                "truncated": lambda: self.truncated_body(req, behaviour.text),
                "refusal": lambda: self.refusal_body(req, behaviour.text),
                "empty": lambda: self.empty_body(req)}[kind]()
        self._send(handler, 200, json.dumps(body).encode(), behaviour.headers)
