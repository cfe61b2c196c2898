"""A fake Gemini API (``POST /{version}/models/{model}:generateContent``) for SDK-level tests.

The real `google-genai` SDK is pointed at it through ``base_url``, so tests see exactly what the
SDK puts on the wire (path, ``x-goog-api-key`` header, ``inlineData`` parts) and how it reacts to
Google's reply shapes: ``finishReason`` values, ``promptFeedback.blockReason`` for a blocked
prompt, and errors as ``{"error": {"code", "message", "status"}}`` with gRPC status names. It
lists its models (``GET /v1beta/models``) and answers 404 ``NOT_FOUND`` to a model it does not
serve and to an API version other than ``v1beta``/``v1``/``v1alpha``.
"""

from __future__ import annotations

import re

from visphy_plugins.testing.fake_server import Behaviour, FakeProviderServer, Recorded

_PATH = re.compile(r"^/(?P<version>[^/]+)/models/(?P<model>[^/:]+):generateContent$")
VERSIONS = ("v1beta", "v1", "v1alpha")

#: Google's canonical status name for an HTTP code (what the real API puts in ``error.status``).
STATUS_NAMES = {400: "INVALID_ARGUMENT", 401: "UNAUTHENTICATED", 403: "PERMISSION_DENIED",
                404: "NOT_FOUND", 409: "ABORTED", 429: "RESOURCE_EXHAUSTED", 499: "CANCELLED",
                500: "INTERNAL", 501: "NOT_IMPLEMENTED", 503: "UNAVAILABLE",
                504: "DEADLINE_EXCEEDED"}


def model_of(req: Recorded) -> str | None:
    """The model named in a recorded request's path (``gemini-2.5-pro``), or None."""
    m = _PATH.match(req.path)
    return m.group("model") if m else None


def blocked_candidate(reason: str = "SAFETY") -> Behaviour:
    """A candidate stopped by a filter (``finishReason: SAFETY`` and no text), not a blocked
    prompt: the ``refusal`` behaviour covers the latter."""
    return Behaviour("refusal", text=f"candidate:{reason}")


class FakeGeminiServer(FakeProviderServer):
    """`FakeProviderServer` speaking the Gemini API's ``generateContent``."""

    name = "gemini"
    lists_models = True

    def handles(self, req: Recorded) -> bool:
        return req.method == "POST" and _PATH.match(req.path) is not None

    def in_api(self, req: Recorded) -> bool:
        m = _PATH.match(req.path)
        return m is not None and m.group("version") in VERSIONS

    def is_listing(self, req: Recorded) -> bool:
        return req.method == "GET" and req.path.rstrip("/") in {f"/{v}/models" for v in VERSIONS}

    def requested_model(self, req: Recorded) -> str:
        return model_of(req) or ""

    def models_body(self, ids: tuple[str, ...]) -> dict:
        return {"models": [{"name": f"models/{mid}", "version": "001", "displayName": mid,
                            "inputTokenLimit": 1048576, "outputTokenLimit": 65536,
                            "supportedGenerationMethods": ["generateContent", "countTokens"]}
                           for mid in ids]}

    def unknown_model_body(self, req: Recorded, model: str) -> dict:
        m = _PATH.match(req.path)
        version = m.group("version") if m else "v1beta"
        return self.error_body(404, f"models/{model} is not found for API version {version}, "
                               "or is not supported for generateContent. Call ListModels to see "
                               "the list of available models and their supported methods.")

    @staticmethod
    def _usage(usage: dict[str, int]) -> dict[str, int]:
        prompt = int(usage.get("input_tokens", 0))
        out = int(usage.get("output_tokens", 0))
        thoughts = int(usage.get("reasoning_tokens", 0))
        meta = {"promptTokenCount": prompt, "candidatesTokenCount": out,
                "totalTokenCount": prompt + out + thoughts}
        if thoughts:
            meta["thoughtsTokenCount"] = thoughts
        if usage.get("cached_input_tokens"):
            meta["cachedContentTokenCount"] = int(usage["cached_input_tokens"])
        return meta

    def _reply(self, req: Recorded, parts: list[dict] | None, finish: str,
               usage: dict[str, int]) -> dict:
        content: dict = {"role": "model"}
        if parts is not None:
            content["parts"] = parts
        return {"candidates": [{"content": content, "finishReason": finish, "index": 0}],
                "usageMetadata": self._usage(usage), "modelVersion": model_of(req) or ""}

    def ok_body(self, req: Recorded, text: str, usage: dict[str, int]) -> dict:
        return self._reply(req, [{"text": text}], "STOP", usage)

    def truncated_body(self, req: Recorded, text: str) -> dict:
        return self._reply(req, [{"text": text}], "MAX_TOKENS",
                           {"input_tokens": 1200, "output_tokens": 512})

    def refusal_body(self, req: Recorded, text: str) -> dict:
        if text.startswith("candidate:"):
            return self._reply(req, None, text.split(":", 1)[1],
                               {"input_tokens": 1200, "output_tokens": 0})
        return {"promptFeedback": {"blockReason": "SAFETY"},
                "usageMetadata": {"promptTokenCount": 1200, "totalTokenCount": 1200},
                "modelVersion": model_of(req) or ""}

    def empty_body(self, req: Recorded) -> dict:
        return self._reply(req, [], "STOP", {"input_tokens": 1200, "output_tokens": 0})

    def error_body(self, code: int, message: str) -> dict:
        return {"error": {"code": code, "message": message,
                          "status": STATUS_NAMES.get(code, "UNKNOWN")}}
