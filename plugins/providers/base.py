"""The provider-neutral half of every API caller: parts, completions, retries, cost.

A `ProviderClient` makes exactly one HTTP attempt through its provider's official async SDK and
either returns a `Completion` or raises a classified `visphy_core.calls.retry.CallError`.
`ApiCaller`
adds the rest, once for every provider: the key, retries with backoff and ``Retry-After``, the
endpoint's adaptive concurrency, empty replies retried, usage normalised, cost from the price
table. `ApiModel` is the model adapter built on it; judges use `ApiCaller` directly.
"""

from __future__ import annotations

import json
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Literal

from visphy_core.api.calls import (
    CallError,
    CallErrorKind,
    Price,
    RetryPolicy,
    call_with_retries,
    limiter_for,
    require_key,
)
from visphy_core.api.model import Model, ModelRequest, ModelResponse


@dataclass(frozen=True)
class Part:
    """One piece of a user message: text, a PNG image or an MP4 video."""

    kind: Literal["text", "image", "video"]
    text: str = ""
    data: bytes = b""

    @property
    def mime(self) -> str:
        return {"image": "image/png", "video": "video/mp4"}.get(self.kind, "text/plain")


@dataclass
class Completion:
    """One successful HTTP exchange, normalised."""

    text: str
    usage: dict[str, int] = field(default_factory=dict)  # input/output/cached_input/reasoning
    finish_reason: str | None = None  # stop | length | refusal | content_filter | other
    refusal: str | None = None
    model_id: str = ""
    raw: dict[str, Any] = field(default_factory=dict)


class ProviderClient(ABC):
    """One provider's wire format over its official SDK (async)."""

    provider: str = ""

    def __init__(self, settings: Any, api_key: str):
        self.settings = settings
        self.api_key = api_key

    @property
    def endpoint(self) -> str:
        """What the adaptive limiter is keyed by: provider and base URL."""
        return f"{self.provider}:{self.settings.get('base_url') or 'default'}"

    @abstractmethod
    async def complete(self, parts: list[Part], max_output_tokens: int) -> Completion:
        """One attempt; raises `CallError` (classified) on any failure."""

    async def aclose(self) -> None:
        """Close the SDK client."""


def make_client(settings: Any, api_key: str) -> ProviderClient:
    """The `ProviderClient` for ``settings.provider`` (imports only that provider's SDK)."""
    provider = str(settings.provider)
    if provider == "openai":
        from visphy_plugins.providers.openai_api import OpenAIClient as cls
    elif provider == "anthropic":
        from visphy_plugins.providers.anthropic_api import AnthropicClient as cls
    elif provider == "gemini":
        from visphy_plugins.providers.gemini_api import GeminiClient as cls
    else:
        raise ValueError(f"unknown provider {provider!r}; valid: openai, anthropic, gemini")
    return cls(settings, api_key)


#: Settings that change a reply (part of the cache identity); transport settings (base URL,
#: timeouts, retries, concurrency, prices) do not.
GENERATION_KEYS = ("provider", "model_id", "max_output_tokens", "max_tokens_param",
                   "temperature", "reasoning_effort", "thinking_budget", "seed", "image_detail")


@dataclass
class CallResult:
    completion: Completion | None
    error: CallError | None
    attempts: int
    latency_s: float
    cost_usd: float | None


class ApiCaller:
    """Key, client, retries, limiter and cost for one configured API model or judge."""

    def __init__(self, settings: Any, who: str):
        self.settings = settings
        self.who = who
        self.policy = RetryPolicy.from_cfg(settings)
        self.price = Price.from_cfg(settings.get("price"))
        self._client: ProviderClient | None = None

    @property
    def key_env(self) -> str | None:
        env = self.settings.get("api_key_env")
        return str(env) if env else None

    def api_key(self) -> str:
        """The key (`MissingKey` when absent); ``"none"`` when the config names no variable."""
        return require_key(self.key_env, self.who) if self.key_env else "none"

    def check_ready(self) -> None:
        self.api_key()

    def identity(self) -> dict[str, Any]:
        return {k: self.settings.get(k) for k in GENERATION_KEYS}

    def client(self) -> ProviderClient:
        if self._client is None:
            self._client = make_client(self.settings, self.api_key())
        return self._client

    async def complete(self, parts: list[Part]) -> CallResult:
        """One logical call: retried, limited, priced. Never raises a `CallError`."""
        client = self.client()
        conc = self.settings.get("concurrency") or {}
        limiter = limiter_for(client.endpoint, int(conc.get("initial", 4)),
                              int(conc.get("maximum", 16)))
        max_tokens = int(self.settings.max_output_tokens)

        async def attempt() -> Completion:
            completion = await client.complete(parts, max_tokens)
            if not completion.text.strip() and completion.finish_reason not in (
                    "length", "refusal", "content_filter"):
                raise CallError(CallErrorKind.empty,
                                f"empty reply (finish reason {completion.finish_reason})")
            return completion

        start = time.perf_counter()
        try:
            completion, attempts = await call_with_retries(attempt, self.policy, limiter)
        except CallError as exc:
            return CallResult(None, exc, getattr(exc, "attempts", 1),
                              time.perf_counter() - start, None)
        cost = self.price.cost(completion.usage) if self.price else None
        return CallResult(completion, None, attempts, time.perf_counter() - start, cost)

    async def aclose(self) -> None:
        if self._client is not None:
            await self._client.aclose()
            self._client = None


class ApiModel(Model):
    """A model served by a provider API (``model=gpt5``, ``claude``, ``gemini25pro``, ...)."""

    version = "1"

    def __init__(self, cfg: Any):
        super().__init__(cfg)
        self.name = str(cfg.name)
        self.api = ApiCaller(cfg, f"model={self.name}")
        self.needs_key = self.api.key_env

    def check_ready(self) -> None:
        self.api.check_ready()

    def identity(self) -> str:
        return json.dumps(["api", self.version, self.api.identity()], sort_keys=True)

    def describe(self) -> dict:
        return {**super().describe(), "provider": str(self.cfg.provider),
                "model_id": str(self.cfg.model_id)}

    def generate(self, request: ModelRequest) -> ModelResponse:
        """Blocking call outside a run (a run uses `agenerate` on its own loop): the client
        is opened and closed on one event loop."""
        import asyncio

        async def once() -> ModelResponse:
            try:
                return await self.agenerate(request)
            finally:
                await self.aclose()

        return asyncio.run(once())

    async def agenerate(self, request: ModelRequest) -> ModelResponse:
        parts = [Part("text", text=request.prompt)]
        parts += [Part("image", data=img.png) for img in request.images]
        result = await self.api.complete(parts)
        if result.error is not None:
            return ModelResponse(text="", error=result.error.describe(),
                                 error_kind=result.error.kind.value,
                                 latency_s=result.latency_s,
                                 transport_attempts=result.attempts)
        c = result.completion
        assert c is not None
        return ModelResponse(text=c.text, usage=dict(c.usage), cost_usd=result.cost_usd,
                             latency_s=result.latency_s, raw=c.raw,
                             finish_reason=c.finish_reason, refusal=c.refusal,
                             transport_attempts=result.attempts, model_id=c.model_id)

    async def aclose(self) -> None:
        await self.api.aclose()
