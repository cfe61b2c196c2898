"""A fake OpenAI Chat Completions server (also standing in for DashScope, vLLM, Ollama, ...).

Serves ``POST <prefix>/chat/completions`` and ``GET <prefix>/models`` under the official prefix
``/v1`` and DashScope's compatible mode ``/compatible-mode/v1`` (`PREFIXES`), so one fake covers
every OpenAI-family config. Point the SDK at ``server.url + "/v1"`` (or the compatible prefix); any
other prefix is a 404, as is a model id the fake does not serve (OpenAI's ``model_not_found``).
With ``models=None`` it takes any prefix and any model and lists none.
Bodies follow the real ``chat.completion`` object closely enough that the official SDK parses
them exactly as it parses OpenAI's, including the usage details the cost code reads.
"""

from __future__ import annotations

import itertools
import time
from typing import Any

from visphy_plugins.testing.fake_server import FakeProviderServer, Recorded

_ids = itertools.count(1)

#: The path prefixes of the OpenAI API and of DashScope's compatible mode.
PREFIXES = ("/v1", "/compatible-mode/v1")

#: The ``type`` OpenAI puts in error bodies, per status (what the SDK surfaces as ``e.type``).
_ERROR_TYPES = {400: "invalid_request_error", 401: "invalid_request_error",
                403: "permission_error", 404: "invalid_request_error",
                429: "rate_limit_exceeded"}


class FakeOpenAIServer(FakeProviderServer):
    """Chat Completions wire format over the scripted base server."""

    name = "openai"
    lists_models = True

    def handles(self, req: Recorded) -> bool:
        return req.method == "POST" and req.path.rstrip("/").endswith("/chat/completions")

    def in_api(self, req: Recorded) -> bool:
        return req.path.rstrip("/") in {f"{p}/chat/completions" for p in PREFIXES}

    def is_listing(self, req: Recorded) -> bool:
        return req.method == "GET" and req.path.rstrip("/") in {f"{p}/models" for p in PREFIXES}

    def requested_model(self, req: Recorded) -> str:
        body = req.json
        return str(body.get("model", "")) if isinstance(body, dict) else ""

    def models_body(self, ids: tuple[str, ...]) -> dict:
        return {"object": "list", "data": [{"id": mid, "object": "model", "created": 1700000000,
                                            "owned_by": "system"} for mid in ids]}

    def unknown_model_body(self, req: Recorded, model: str) -> dict:
        return {"error": {"message": f"The model `{model}` does not exist or you do not have "
                          "access to it.", "type": "invalid_request_error", "param": None,
                          "code": "model_not_found"}}

    def _model(self, req: Recorded) -> str:
        body = req.json
        return str(body.get("model", "fake-model")) if isinstance(body, dict) else "fake-model"

    def _completion(self, req: Recorded, message: dict[str, Any], finish_reason: str,
                    usage: dict[str, int]) -> dict:
        prompt = int(usage.get("input_tokens", 0))
        completion = int(usage.get("output_tokens", 0))
        return {
            "id": f"chatcmpl-fake{next(_ids)}",
            "object": "chat.completion",
            "created": int(time.time()),
            "model": self._model(req),
            "choices": [{"index": 0, "message": {"role": "assistant", "annotations": [],
                                                 **message},
                         "logprobs": None, "finish_reason": finish_reason}],
            "usage": {
                "prompt_tokens": prompt,
                "completion_tokens": completion,
                "total_tokens": prompt + completion,
                "prompt_tokens_details": {"cached_tokens": int(usage.get("cached_input_tokens",
                                                                         0)),
                                          "audio_tokens": 0},
                "completion_tokens_details": {"reasoning_tokens": int(usage.get(
                    "reasoning_tokens", 0)), "audio_tokens": 0},
            },
            "service_tier": "default",
            "system_fingerprint": "fp_fake",
        }

    def ok_body(self, req: Recorded, text: str, usage: dict[str, int]) -> dict:
        return self._completion(req, {"content": text, "refusal": None}, "stop", usage)

    def truncated_body(self, req: Recorded, text: str) -> dict:
        return self._completion(req, {"content": text, "refusal": None}, "length",
                                {"input_tokens": 1200, "output_tokens": 512})

    def refusal_body(self, req: Recorded, text: str) -> dict:
        return self._completion(req, {"content": None, "refusal": text}, "stop",
                                {"input_tokens": 1200, "output_tokens": 12})

    def empty_body(self, req: Recorded) -> dict:
        return self._completion(req, {"content": "", "refusal": None}, "stop",
                                {"input_tokens": 1200, "output_tokens": 0})

    def error_body(self, code: int, message: str) -> dict:
        return {"error": {"message": message,
                          "type": _ERROR_TYPES.get(code, "server_error" if code >= 500
                                                   else "invalid_request_error"),
                          "param": None,
                          "code": {401: "invalid_api_key", 429: "rate_limit_exceeded"}
                          .get(code)}}
