"""Gemini (Google GenAI, the Gemini API) as a `ProviderClient`, over the official ``google-genai``
SDK's async client.

One call is one HTTP attempt: the SDK's own retries are switched off (``HttpRetryOptions(
attempts=1)``) because `ApiCaller` retries every provider the same way, with ``Retry-After`` and
the adaptive limiter. The key travels in the ``x-goog-api-key`` header (the SDK's choice for the
Gemini API; never ``?key=`` in a URL that could end up in a log). Vertex AI is ruled out
explicitly so a stray ``GOOGLE_GENAI_USE_VERTEXAI`` in the environment cannot reroute a run.

What the SDK raises, as observed against `visphy_plugins.testing.fake_gemini` (SDK 3.6.1 on its
default httpx2 transport), and what it becomes:

* an HTTP error: ``errors.ClientError`` / ``errors.ServerError`` (``APIError.code``; the
  ``httpx2.Response`` with its ``Retry-After`` on ``.response``) -> `kind_for_status`;
* no reply within ``timeout``: ``httpx2.ReadTimeout`` (a ``TimeoutException``) -> timeout;
* a dropped connection: ``httpx2.RemoteProtocolError``; a refused one ``httpx2.ConnectError``
  (both ``TransportError``) -> connection;
* a 200 whose body is not JSON: a bare ``json.JSONDecodeError`` (``UnknownApiResponseError`` on
  other paths, pydantic's ``ValidationError`` for JSON of the wrong shape) -> malformed.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

import pydantic
from google import genai
from google.genai import errors, types

from visphy_core.api.calls import CallError, CallErrorKind, kind_for_status, retry_after_seconds
from visphy_plugins.providers.base import Completion, Part, ProviderClient


def _transport_errors() -> tuple[tuple[type[BaseException], ...], tuple[type[BaseException], ...]]:
    """(timeout, connection) exception types of whichever HTTP stacks the SDK may use."""
    timeouts: list[type[BaseException]] = [asyncio.TimeoutError, TimeoutError]
    connection: list[type[BaseException]] = [ConnectionError]
    for name in ("httpx2", "httpx"):
        try:
            mod = __import__(name)
        except ImportError:
            continue
        timeouts.append(mod.TimeoutException)
        connection.append(mod.TransportError)  # after timeouts: ReadTimeout is one too
    try:
        import aiohttp
    except ImportError:
        pass
    else:
        timeouts.append(aiohttp.ServerTimeoutError)
        connection.append(aiohttp.ClientConnectionError)
        connection.append(aiohttp.ClientPayloadError)
    return tuple(timeouts), tuple(connection)


TIMEOUT_ERRORS, CONNECTION_ERRORS = _transport_errors()
MALFORMED_ERRORS = (json.JSONDecodeError, errors.UnknownApiResponseError, pydantic.ValidationError)

#: Candidate finish reasons that mean a filter stopped the answer (treated as a refusal).
FILTERED = frozenset({"SAFETY", "RECITATION", "BLOCKLIST", "PROHIBITED_CONTENT", "SPII",
                      "IMAGE_SAFETY", "IMAGE_PROHIBITED_CONTENT"})


def _name(value: Any) -> str | None:
    """An SDK enum (or a plain string the SDK passed through) as its wire name."""
    if value is None:
        return None
    return str(getattr(value, "value", value))


def finish_reason_of(reason: str | None) -> str | None:
    if reason is None:
        return None
    if reason == "STOP":
        return "stop"
    if reason == "MAX_TOKENS":
        return "length"
    return "content_filter" if reason in FILTERED else "other"


def usage_of(meta: types.GenerateContentResponseUsageMetadata | None) -> dict[str, int]:
    """Normalised usage: thinking tokens are billed as output, so they count in it."""
    if meta is None:
        return {}
    thoughts = meta.thoughts_token_count or 0
    return {"input_tokens": meta.prompt_token_count or 0,
            "output_tokens": (meta.candidates_token_count or 0) + thoughts,
            "cached_input_tokens": meta.cached_content_token_count or 0,
            "reasoning_tokens": thoughts}


def to_sdk_part(part: Part) -> types.Part:
    """Text as text, images and videos inline (base64 in the body: fine for a few MB)."""
    if part.kind == "text":
        return types.Part.from_text(text=part.text)
    return types.Part.from_bytes(data=part.data, mime_type=part.mime)


def parse_response(resp: types.GenerateContentResponse, configured_id: str) -> Completion:
    """A `Completion` from a reply: answer text without thoughts, reason, usage, model."""
    usage = usage_of(resp.usage_metadata)
    model_id = resp.model_version or configured_id
    candidate = resp.candidates[0] if resp.candidates else None
    raw_usage = (resp.usage_metadata.model_dump(mode="json", exclude_none=True)
                 if resp.usage_metadata else {})
    if candidate is None:
        feedback = resp.prompt_feedback
        block = _name(feedback.block_reason) if feedback else None
        refusal = None
        reason = None
        if block:
            reason = "refusal"
            message = feedback.block_reason_message if feedback else None
            refusal = f"prompt blocked: {block}" + (f" ({message})" if message else "")
        return Completion(text="", usage=usage, finish_reason=reason, refusal=refusal,
                          model_id=model_id, raw={"model_version": resp.model_version,
                                                  "block_reason": block, "usage": raw_usage})
    parts = candidate.content.parts if candidate.content and candidate.content.parts else []
    text = "".join(p.text for p in parts if p.text and not p.thought)
    wire_reason = _name(candidate.finish_reason)
    reason = finish_reason_of(wire_reason)
    refusal = f"answer stopped by filter: {wire_reason}" if reason == "content_filter" else None
    return Completion(text=text, usage=usage, finish_reason=reason, refusal=refusal,
                      model_id=model_id, raw={"model_version": resp.model_version,
                                              "finish_reason": wire_reason, "usage": raw_usage})


def classify(exc: BaseException) -> CallError | None:
    """The `CallError` for an exception the SDK raised, or None when it is not a call failure."""
    if isinstance(exc, errors.APIError):
        headers = getattr(getattr(exc, "response", None), "headers", None)
        code = exc.code if isinstance(exc.code, int) else 500
        return CallError(kind_for_status(code), f"{exc.status or ''} {exc.message or exc}",
                         status=code,
                         retry_after_s=retry_after_seconds(dict(headers) if headers else None))
    if isinstance(exc, TIMEOUT_ERRORS):
        return CallError(CallErrorKind.timeout, f"{type(exc).__name__}: {exc}")
    if isinstance(exc, CONNECTION_ERRORS):
        return CallError(CallErrorKind.connection, f"{type(exc).__name__}: {exc}")
    if isinstance(exc, MALFORMED_ERRORS):
        return CallError(CallErrorKind.malformed, f"unparsable reply: {type(exc).__name__}: "
                         f"{str(exc)[:200]}")
    return None


class GeminiClient(ProviderClient):
    """``generateContent`` through ``genai.Client(...).aio``; one attempt per `complete`."""

    provider = "gemini"

    def __init__(self, settings: Any, api_key: str):
        super().__init__(settings, api_key)
        options: dict[str, Any] = {
            "timeout": int(float(settings.get("timeout_s") or 600.0) * 1000),
            "retry_options": types.HttpRetryOptions(attempts=1)}
        if settings.get("base_url"):
            options["base_url"] = str(settings.get("base_url"))
        self._client = genai.Client(api_key=api_key, vertexai=False,
                                    http_options=types.HttpOptions(**options))

    def _config(self, max_output_tokens: int) -> types.GenerateContentConfig:
        s = self.settings
        config: dict[str, Any] = {"max_output_tokens": int(max_output_tokens)}
        if s.get("temperature") is not None:
            config["temperature"] = float(s.get("temperature"))
        if s.get("seed") is not None:
            config["seed"] = int(s.get("seed"))
        if s.get("thinking_budget") is not None:
            config["thinking_config"] = types.ThinkingConfig(
                thinking_budget=int(s.get("thinking_budget")))
        return types.GenerateContentConfig(**config)

    async def complete(self, parts: list[Part], max_output_tokens: int) -> Completion:
        model_id = str(self.settings.model_id)
        contents = [types.Content(role="user", parts=[to_sdk_part(p) for p in parts])]
        try:
            resp = await self._client.aio.models.generate_content(
                model=model_id, contents=contents, config=self._config(max_output_tokens))
        except Exception as exc:
            error = classify(exc)
            if error is None:
                raise
            raise error from exc
        return parse_response(resp, model_id)

    async def aclose(self) -> None:
        await self._client.aio.aclose()
        self._client.close()
