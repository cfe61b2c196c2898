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

Like the real services, a fake serves its provider's model list (``GET /v1/models``; Gemini's
``GET /v1beta/models``) and answers 404, in the provider's error format, to a model id it does not
serve and to a path outside its API (a wrong base URL): ``models`` names the ids it serves, by
default every ``model_id`` of that provider in ``conf/model/`` and ``conf/judge/``
(`known_models`); ``models=None`` serves no list and takes any model id on any path prefix (a
server that does not list its models). Listings and refusals are kept in ``gated``, apart from
``requests`` (which holds what reached the script).

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
from functools import lru_cache
from importlib.resources import files
from typing import Any, Callable, Iterable
from urllib.parse import parse_qs, urlsplit

import yaml


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


@lru_cache(maxsize=None)
def known_models(provider: str) -> tuple[str, ...]:
    """Every ``model_id`` the API model configs and the judge configs
    (``visphy_conf/{model,judge}/*.yaml``) give ``provider`` (``openai`` when a config names
    no provider), sorted."""
    ids: set[str] = set()
    for group in ("model", "judge"):
        for entry in files("visphy_conf").joinpath(group).iterdir():
            if not entry.name.endswith(".yaml"):
                continue
            data = yaml.safe_load(entry.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or "model_id" not in data:
                continue
            if group == "model" and "schema_api_model" not in (data.get("defaults") or []):
                continue  # a video model (its own fake) or a baseline
            model_id = str(data["model_id"])
            if data.get("provider", "openai") == provider and model_id and "?" not in model_id \
                    and "$" not in model_id:
                ids.add(model_id)
    return tuple(sorted(ids))


#: ``models`` default: the provider's `known_models`.
KNOWN = object()


class FakeProviderServer:
    """Base: HTTP plumbing, recording and the script. Subclasses define the wire format."""

    #: Header names whose values are the API key (checked by tests: never in URLs or logs).
    name = "fake"
    #: Whether this wire format lists models and refuses unknown ones (`gate`).
    lists_models = False

    def __init__(self, default: Callable[[Recorded], Behaviour] | None = None,
                 models: Iterable[str] | None | object = KNOWN):
        self.models: tuple[str, ...] | None = (
            known_models(self.name) if models is KNOWN
            else None if models is None else tuple(models))  # type: ignore[arg-type]
        self.gated: list[tuple[Recorded, int]] = []  # model listings and refusals, with status
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

    def is_listing(self, req: Recorded) -> bool:
        """Whether ``req`` asks for the model list."""
        return False

    def in_api(self, req: Recorded) -> bool:
        """Whether ``req`` is on one of the provider's real paths (``handles`` may be looser)."""
        return self.handles(req)

    def requested_model(self, req: Recorded) -> str:
        return ""

    def models_body(self, ids: tuple[str, ...]) -> dict:
        raise NotImplementedError

    def unknown_model_body(self, req: Recorded, model: str) -> dict:
        return self.error_body(404, f"model {model!r} not found")

    def gate(self, req: Recorded) -> tuple[int, dict] | None:
        """The model list, or a 404 for an unknown model or a path outside the API; None lets
        the request through to the script. Nothing is gated when ``models`` is None."""
        if self.models is None or not self.lists_models:
            return None
        if self.is_listing(req):
            return 200, self.models_body(self.models)
        if self.handles(req):
            if not self.in_api(req):
                return 404, self.error_body(404, f"Invalid URL ({req.method} {req.path})")
            model = self.requested_model(req)
            if model not in self.models:
                return 404, self.unknown_model_body(req, model)
        return None

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
        gated = self.gate(req)
        if gated is not None:
            code, body = gated
            with self._lock:
                self.gated.append((req, code))
            self._send(handler, code, json.dumps(body).encode())
            return
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
