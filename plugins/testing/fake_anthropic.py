"""A fake Anthropic Messages API (``POST /v1/messages``) for SDK-level tests.

The real `anthropic` SDK is pointed at it through ``base_url=server.url`` (the SDK appends
``/v1/messages``), so tests see exactly what the SDK puts on the wire (auth and
``anthropic-version`` headers, base64 ``image`` blocks, ``thinking``) and how it reacts to
Anthropic's reply shapes: ``stop_reason`` values (``end_turn``, ``max_tokens``, ``refusal``),
an empty ``content`` list, and errors as ``{"type": "error", "error": {"type", "message"}}``
(the ``error.type`` names the real API uses, 529 ``overloaded_error`` included). It lists its
models (``GET /v1/models``) and refuses a model it does not serve with 404 ``not_found_error``.
"""

from __future__ import annotations

import itertools

from visphy_plugins.testing.fake_server import FakeProviderServer, Recorded

PATH = "/v1/messages"
MODELS_PATH = "/v1/models"

#: Anthropic's ``error.type`` for an HTTP status (what the real API puts in the error body).
ERROR_TYPES = {400: "invalid_request_error", 401: "authentication_error",
               403: "permission_error", 404: "not_found_error", 413: "request_too_large",
               429: "rate_limit_error", 500: "api_error", 504: "timeout_error",
               529: "overloaded_error"}

_ids = itertools.count(1)


def model_of(req: Recorded) -> str:
    """The model a recorded request asked for ("" when the body names none)."""
    body = req.json
    return str(body.get("model", "")) if isinstance(body, dict) else ""


class FakeAnthropicServer(FakeProviderServer):
    """`FakeProviderServer` speaking the Anthropic Messages API."""

    name = "anthropic"
    lists_models = True

    def handles(self, req: Recorded) -> bool:
        return req.method == "POST" and req.path == PATH

    def is_listing(self, req: Recorded) -> bool:
        return req.method == "GET" and req.path.rstrip("/") == MODELS_PATH

    def requested_model(self, req: Recorded) -> str:
        return model_of(req)

    def models_body(self, ids: tuple[str, ...]) -> dict:
        data = [{"type": "model", "id": mid, "display_name": mid,
                 "created_at": "2025-09-29T00:00:00Z"} for mid in ids]
        return {"data": data, "has_more": False, "first_id": ids[0] if ids else None,
                "last_id": ids[-1] if ids else None}

    def unknown_model_body(self, req: Recorded, model: str) -> dict:
        return {"type": "error", "error": {"type": "not_found_error", "message": f"model: {model}"},
                "request_id": "req_fake404"}

    @staticmethod
    def _usage(usage: dict[str, int]) -> dict[str, int]:
        """Anthropic's usage from the test's totals: the API's ``input_tokens`` is the input
        neither read from nor written to the cache, reported beside the two cache counts (the
        test's ``input_tokens`` is the whole input, ``cached_input_tokens`` a cache read)."""
        read = int(usage.get("cached_input_tokens", 0))
        write = int(usage.get("cache_creation_input_tokens", 0))
        return {"input_tokens": int(usage.get("input_tokens", 0)) - read - write,
                "output_tokens": int(usage.get("output_tokens", 0)),
                "cache_read_input_tokens": read, "cache_creation_input_tokens": write}

    def _reply(self, req: Recorded, content: list[dict], stop_reason: str,
               usage: dict[str, int]) -> dict:
        return {"id": f"msg_fake{next(_ids):06d}", "type": "message", "role": "assistant",
                "model": model_of(req), "content": content, "stop_reason": stop_reason,
                "stop_sequence": None, "usage": self._usage(usage)}

    def ok_body(self, req: Recorded, text: str, usage: dict[str, int]) -> dict:
        return self._reply(req, [{"type": "text", "text": text}], "end_turn", usage)

    def truncated_body(self, req: Recorded, text: str) -> dict:
        return self._reply(req, [{"type": "text", "text": text}], "max_tokens",
                           {"input_tokens": 1200, "output_tokens": 512})

    def refusal_body(self, req: Recorded, text: str) -> dict:
        return self._reply(req, [{"type": "text", "text": text}], "refusal",
                           {"input_tokens": 1200, "output_tokens": 12})

    def empty_body(self, req: Recorded) -> dict:
        return self._reply(req, [], "end_turn", {"input_tokens": 1200, "output_tokens": 0})

    def error_body(self, code: int, message: str) -> dict:
        kind = ERROR_TYPES.get(code, "api_error" if code >= 500 else "invalid_request_error")
        return {"type": "error", "error": {"type": kind, "message": message},
                "request_id": f"req_fake{code}"}
