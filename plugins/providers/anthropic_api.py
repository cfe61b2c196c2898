"""The Anthropic Messages API through the official async SDK (``anthropic``).

One `complete` is one HTTP attempt: the SDK's own retries are off (``max_retries=0``) because
`ApiCaller` retries every provider the same way, with the project's backoff, ``Retry-After``
and adaptive concurrency. Everything the SDK can raise is turned into a classified `CallError`.

Quirks of the installed SDK (2.x) this module works around, found against the fake server:

* ``messages.create`` has no ``temperature`` argument any more (newer Claude models reject it),
  so a configured temperature goes in ``extra_body``; leave it null for models that refuse it.
* The SDK does not validate replies (``_strict_response_validation`` is off): a body without
  ``content`` still becomes a ``Message`` full of ``None``, and a non-JSON content type comes
  back as a plain ``str``. Both are checked here and reported as ``malformed``.
* A 200 whose body is not JSON raises a bare ``json.JSONDecodeError``, not an SDK error.
* ``APITimeoutError`` is a subclass of ``APIConnectionError``: it is matched first.
* The key goes out as ``Authorization: Bearer`` (not ``x-api-key``), with
  ``anthropic-version: 2026-10-21``; ``ANTHROPIC_BASE_URL`` applies when ``base_url`` is null.
"""

from __future__ import annotations

import asyncio
import base64
import json
from typing import Any

import anthropic
import pydantic

from visphy_core.api.calls import CallError, CallErrorKind, kind_for_status, retry_after_seconds
from visphy_plugins.providers.base import Completion, Part, ProviderClient

#: Anthropic ``stop_reason`` → the project's finish reason. A full context window cuts the
#: reply like ``max_tokens`` does, so it counts as ``length`` too.
FINISH_REASONS = {"end_turn": "stop", "stop_sequence": "stop", "max_tokens": "length",
                  "model_context_window_exceeded": "length", "refusal": "refusal"}


class AnthropicClient(ProviderClient):
    """Claude models over the Messages API (``POST /v1/messages``)."""

    provider = "anthropic"

    def __init__(self, settings: Any, api_key: str):
        super().__init__(settings, api_key)
        self._sdk: anthropic.AsyncAnthropic | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    def _client(self) -> anthropic.AsyncAnthropic:
        """The SDK client of the running loop: its connection pool is bound to the loop that
        made it, and `Model.generate` runs each call in a fresh ``asyncio.run``. The httpx
        client is our own `DefaultAsyncHttpxClient` (the SDK's defaults) because the SDK's
        built-in one, when garbage collected, schedules its close on whatever loop is running
        then, which fails ("Event loop is closed") for a client of an earlier, finished loop."""
        loop = asyncio.get_running_loop()
        if self._sdk is None or self._loop is not loop:
            timeout = float(self.settings.get("timeout_s") or 600.0)
            self._sdk = anthropic.AsyncAnthropic(
                api_key=self.api_key, base_url=self.settings.get("base_url") or None,
                max_retries=0, timeout=timeout,
                http_client=anthropic.DefaultAsyncHttpxClient(timeout=timeout))
            self._loop = loop
        return self._sdk

    def request_kwargs(self, parts: list[Part], max_output_tokens: int) -> dict[str, Any]:
        """The ``messages.create`` arguments: one user turn, the parts in the order given."""
        content: list[dict[str, Any]] = []
        for part in parts:
            if part.kind == "video":
                raise CallError(CallErrorKind.bad_request,
                                "Anthropic models take no video; use frames")
            if part.kind == "image":
                content.append({"type": "image", "source": {
                    "type": "base64", "media_type": part.mime,
                    "data": base64.b64encode(part.data).decode("ascii")}})
            else:
                content.append({"type": "text", "text": part.text})
        kwargs: dict[str, Any] = {"model": str(self.settings.model_id),
                                  "max_tokens": int(max_output_tokens),
                                  "messages": [{"role": "user", "content": content}]}
        budget = self.settings.get("thinking_budget")
        if budget:  # null or 0: no extended thinking
            if int(budget) >= int(max_output_tokens):
                raise CallError(CallErrorKind.bad_request,
                                f"thinking_budget {budget} must be below max_output_tokens "
                                f"{max_output_tokens}")
            # The API rejects a temperature together with extended thinking.
            kwargs["thinking"] = {"type": "enabled", "budget_tokens": int(budget)}
        elif self.settings.get("temperature") is not None:
            kwargs["extra_body"] = {"temperature": float(self.settings.temperature)}
        return kwargs

    async def complete(self, parts: list[Part], max_output_tokens: int) -> Completion:
        kwargs = self.request_kwargs(parts, max_output_tokens)
        try:
            message = await self._client().messages.create(**kwargs)
        except anthropic.APIStatusError as exc:
            raise CallError(kind_for_status(exc.status_code),
                            f"{type(exc).__name__}: {exc.api_message or exc.message}",
                            status=exc.status_code,
                            retry_after_s=retry_after_seconds(exc.response.headers)) from None
        except anthropic.APITimeoutError:
            raise CallError(CallErrorKind.timeout, "Anthropic request timed out") from None
        except anthropic.APIConnectionError as exc:
            cause = exc.__cause__
            detail = f" ({type(cause).__name__}: {cause})" if cause else ""
            raise CallError(CallErrorKind.connection, f"{exc.message}{detail}") from None
        except (anthropic.APIResponseValidationError, json.JSONDecodeError, UnicodeDecodeError,
                pydantic.ValidationError) as exc:
            raise CallError(CallErrorKind.malformed,
                            f"unparseable Messages reply: {type(exc).__name__}: {exc}") from None
        return to_completion(message)

    async def aclose(self) -> None:
        sdk, self._sdk = self._sdk, None
        if sdk is not None and self._loop is asyncio.get_running_loop():
            await sdk.close()
        self._loop = None


def _int(value: Any) -> int:
    return value if isinstance(value, int) else 0


def to_completion(message: Any) -> Completion:
    """A `Completion` from a ``Message``; `CallError` (malformed) when the reply lacks the
    shape of one (the SDK builds replies without validating them)."""
    content = getattr(message, "content", None)
    usage: Any = getattr(message, "usage", None)
    if not isinstance(content, list) or not isinstance(getattr(usage, "input_tokens", None), int) \
            or not isinstance(getattr(usage, "output_tokens", None), int):
        raise CallError(CallErrorKind.malformed,
                        f"Messages reply without content or usage: {str(message)[:200]}")
    text = "".join(block.text for block in content
                   if getattr(block, "type", None) == "text" and isinstance(block.text, str))
    stop = getattr(message, "stop_reason", None)
    finish = FINISH_REASONS.get(stop or "", "other")
    refusal = None
    if finish == "refusal":
        details = getattr(message, "stop_details", None)
        refusal = text or getattr(details, "explanation", None) or "refused"
    cache_read = _int(getattr(usage, "cache_read_input_tokens", None))
    cache_write = _int(getattr(usage, "cache_creation_input_tokens", None))
    norm = {"input_tokens": usage.input_tokens + cache_read + cache_write,
            "output_tokens": usage.output_tokens, "cached_input_tokens": cache_read}
    thinking = getattr(getattr(usage, "output_tokens_details", None), "thinking_tokens", None)
    if isinstance(thinking, int):
        norm["reasoning_tokens"] = thinking
    raw = {"id": getattr(message, "id", None), "model": getattr(message, "model", None),
           "stop_reason": stop,
           "usage": {"input_tokens": usage.input_tokens, "output_tokens": usage.output_tokens,
                     "cache_read_input_tokens": cache_read,
                     "cache_creation_input_tokens": cache_write}}
    return Completion(text=text, usage=norm, finish_reason=finish, refusal=refusal,
                      model_id=str(raw["model"] or ""), raw=raw)
