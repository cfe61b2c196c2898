"""OpenAI-family client: Chat Completions through the official ``openai`` SDK.

One client serves OpenAI itself (``gpt5``, ``gpt41``), DashScope's compatible mode
(``qwen3vlplus``) and any OpenAI-compatible local server (``openai_compat``: vLLM, Ollama,
llama.cpp, LM Studio). Chat Completions rather than the Responses API because it is the one
endpoint all of those speak.

SDK behaviour this module relies on (checked against ``FakeOpenAIServer`` with openai 3.57):

* the SDK validates replies non-strictly: a 200 body that is JSON but not a completion comes
  back as whatever it decoded (a ``list``, a ``str``, ``None``, or a ``ChatCompletion`` whose
  fields are all ``None``), and a 200 ``text/html`` body comes back as a ``str``; so the reply
  is checked here and anything without ``choices[0].message`` is ``malformed``;
* a 200 body that is not JSON at all raises a bare ``json.JSONDecodeError`` (not an
  ``APIResponseValidationError``);
* 4xx/5xx raise ``APIStatusError`` subclasses whose message echoes the body, which can quote
  the key: every message is scrubbed of it;
* ``APITimeoutError`` is a subclass of ``APIConnectionError``: it is tested first.
"""

from __future__ import annotations

import asyncio
import base64
import json
from typing import Any

import openai

from visphy_core.api.calls import CallError, CallErrorKind, kind_for_status, retry_after_seconds
from visphy_plugins.providers.base import Completion, Part, ProviderClient

_FINISH = {"stop": "stop", "length": "length", "content_filter": "content_filter",
           "refusal": "refusal"}


def _data_url(part: Part) -> str:
    return f"data:{part.mime};base64,{base64.b64encode(part.data).decode('ascii')}"


def _count(obj: Any, name: str) -> int:
    """An integer usage field; absent, null or nonsense counts as 0 (compatible servers vary)."""
    try:
        return int(getattr(obj, name, 0) or 0)
    except (TypeError, ValueError):
        return 0


def normalise_usage(usage: Any) -> dict[str, int]:
    """Chat Completions usage in visphy's names; ``{}`` when the server reported none."""
    if usage is None or not hasattr(usage, "prompt_tokens"):
        return {}
    return {"input_tokens": _count(usage, "prompt_tokens"),
            "output_tokens": _count(usage, "completion_tokens"),
            "cached_input_tokens": _count(getattr(usage, "prompt_tokens_details", None),
                                          "cached_tokens"),
            "reasoning_tokens": _count(getattr(usage, "completion_tokens_details", None),
                                       "reasoning_tokens")}


def _text(content: Any) -> str | None:
    """The message text; some compatible servers send a list of parts instead of a string."""
    if content is None or isinstance(content, str):
        return content or ""
    if isinstance(content, list):
        return "".join(str(p.get("text", "")) for p in content if isinstance(p, dict))
    return None


class OpenAIClient(ProviderClient):
    """One Chat Completions attempt per `complete` call; the SDK's own retries are off
    (``max_retries=0``) because `ApiCaller` retries with the project's policy and limiter."""

    provider = "openai"

    def __init__(self, settings: Any, api_key: str):
        super().__init__(settings, api_key)
        self._sdk: openai.AsyncOpenAI | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    def _client(self) -> openai.AsyncOpenAI:
        """The SDK client of the running loop: its connection pool is bound to the loop that
        made it, and `Model.generate` runs each call in a fresh ``asyncio.run``."""
        loop = asyncio.get_running_loop()
        if self._sdk is None or self._loop is not loop:
            timeout = float(self.settings.get("timeout_s") or 600)
            # Our own `DefaultAsyncHttpxClient` (the SDK's defaults): the SDK's built-in one
            # schedules its close on whatever loop runs when it is garbage collected, which
            # fails noisily for a client of an earlier, finished loop.
            self._sdk = openai.AsyncOpenAI(
                api_key=self.api_key, base_url=self.settings.get("base_url") or None,
                max_retries=0, timeout=timeout,
                http_client=openai.DefaultAsyncHttpxClient(timeout=timeout))
            self._loop = loop
        return self._sdk

    def _scrub(self, message: str) -> str:
        key = self.api_key
        return message.replace(key, "[REDACTED]") if key and len(key) >= 4 else message

    def request_kwargs(self, parts: list[Part], max_output_tokens: int) -> dict[str, Any]:
        """The ``chat.completions.create`` arguments: one user message, optional knobs only
        when set (compatible servers reject parameters they do not know)."""
        detail = self.settings.get("image_detail")
        content: list[dict[str, Any]] = []
        for part in parts:
            if part.kind == "text":
                content.append({"type": "text", "text": part.text})
            elif part.kind == "image":
                image: dict[str, Any] = {"url": _data_url(part)}
                if detail:
                    image["detail"] = str(detail)
                content.append({"type": "image_url", "image_url": image})
            else:
                content.append({"type": "video_url", "video_url": {"url": _data_url(part)}})
        param = str(self.settings.get("max_tokens_param") or "max_completion_tokens")
        kwargs: dict[str, Any] = {"model": str(self.settings.model_id),
                                  "messages": [{"role": "user", "content": content}],
                                  param: int(max_output_tokens)}
        for name, cast in (("temperature", float), ("reasoning_effort", str), ("seed", int)):
            value = self.settings.get(name)
            if value is not None:
                kwargs[name] = cast(value)
        return kwargs

    async def complete(self, parts: list[Part], max_output_tokens: int) -> Completion:
        kwargs = self.request_kwargs(parts, max_output_tokens)
        try:
            response = await self._client().chat.completions.create(**kwargs)
        except openai.APIStatusError as exc:
            raise CallError(kind_for_status(exc.status_code), self._scrub(str(exc)),
                            status=exc.status_code,
                            retry_after_s=retry_after_seconds(exc.response.headers)) from None
        except openai.APITimeoutError:
            raise CallError(CallErrorKind.timeout, "request timed out") from None
        except openai.APIConnectionError as exc:
            cause = exc.__cause__
            detail = f": {type(cause).__name__}: {cause}" if cause else ""
            raise CallError(CallErrorKind.connection,
                            self._scrub(f"connection error{detail}")) from None
        except (openai.APIResponseValidationError, json.JSONDecodeError) as exc:
            raise CallError(CallErrorKind.malformed,
                            self._scrub(f"unreadable reply: {exc}")) from None
        except openai.APIError as exc:
            raise CallError(CallErrorKind.malformed, self._scrub(str(exc))) from None
        except openai.OpenAIError as exc:  # a client-side setup problem: retrying cannot help
            raise CallError(CallErrorKind.bad_request, self._scrub(str(exc))) from None
        return self.parse(response)

    def parse(self, response: Any) -> Completion:
        """A `Completion` from the SDK's (non-strictly validated) reply, or ``malformed``."""
        choices = getattr(response, "choices", None)
        if not isinstance(choices, list) or not choices:
            raise CallError(CallErrorKind.malformed,
                            f"reply without choices ({type(response).__name__})")
        choice = choices[0]
        message = getattr(choice, "message", None)
        text = _text(getattr(message, "content", None)) if message is not None else None
        if text is None:
            raise CallError(CallErrorKind.malformed, "reply without a readable message")
        raw_reason = getattr(choice, "finish_reason", None)
        reason = _FINISH.get(str(raw_reason), "other")
        refusal = getattr(message, "refusal", None)
        if isinstance(refusal, str) and refusal.strip():
            reason = "refusal"
        else:
            refusal = None
        usage = normalise_usage(getattr(response, "usage", None))
        model_id = str(getattr(response, "model", None) or self.settings.model_id)
        raw = {"id": getattr(response, "id", None), "model": model_id,
               "finish_reason": raw_reason, "usage": usage}
        return Completion(text=text, usage=usage, finish_reason=reason, refusal=refusal,
                          model_id=model_id, raw=raw)

    async def aclose(self) -> None:
        sdk, loop, self._sdk, self._loop = self._sdk, self._loop, None, None
        if sdk is None:
            return
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:  # a client of a finished loop cannot be closed; it is dropped
            await sdk.close()
