"""Calling a provider politely: classified errors, retries with backoff, adaptive concurrency.

Provider adapters (plugins) turn their SDK's exceptions into `CallError` with a `CallErrorKind`;
everything else here is provider-neutral:

* `call_with_retries` retries the transient kinds (rate limits, 5xx, timeouts, dropped
  connections, malformed or empty bodies) with exponential backoff, honouring ``Retry-After``;
  an error that retrying cannot fix (a bad request, an auth failure) is raised at once.
* `AdaptiveLimiter` bounds the calls in flight per provider endpoint: it halves its limit on a
  429 and grows it by one after a run of successes (additive increase, multiplicative decrease),
  between 1 and the configured maximum.
"""

from __future__ import annotations

import asyncio
import email.utils
import random
import time
from contextlib import asynccontextmanager
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, AsyncIterator, Awaitable, Callable, Mapping, TypeVar

T = TypeVar("T")


class CallErrorKind(StrEnum):
    rate_limit = "rate_limit"     # 429 / overloaded: back off, retry
    server = "server"             # 5xx, 409, 529: retry
    timeout = "timeout"           # no answer within the per-call timeout: retry
    connection = "connection"     # connection refused / reset: retry
    malformed = "malformed"       # a body that does not parse in the provider's format: retry
    empty = "empty"               # a well-formed reply with no content at all: retry
    auth = "auth"                 # 401/403: the key is wrong; no retry, the run stops
    bad_request = "bad_request"   # 400/404/413/422: the request itself is wrong; no retry


RETRYABLE = frozenset({CallErrorKind.rate_limit, CallErrorKind.server, CallErrorKind.timeout,
                       CallErrorKind.connection, CallErrorKind.malformed, CallErrorKind.empty})


class CallError(Exception):
    """One failed provider call, classified."""

    def __init__(self, kind: CallErrorKind, message: str, status: int | None = None,
                 retry_after_s: float | None = None):
        super().__init__(message)
        self.kind = CallErrorKind(kind)
        self.status = status
        self.retry_after_s = retry_after_s

    @property
    def retryable(self) -> bool:
        return self.kind in RETRYABLE

    def describe(self) -> str:
        status = f" HTTP {self.status}" if self.status else ""
        return f"{self.kind.value}{status}: {' '.join(str(self).split())[:500]}"


def kind_of_description(text: str | None) -> CallErrorKind | None:
    """The kind a `CallError.describe` text starts with (``"rate_limit HTTP 429: ..."``, the
    ``failure_detail`` of a ``model_error`` row), or None for text in another format."""
    head = (text or "").split(":", 1)[0].split(" ", 1)[0].strip()
    try:
        return CallErrorKind(head)
    except ValueError:
        return None


def kind_for_status(status: int) -> CallErrorKind:
    """The error kind of an HTTP status code."""
    if status == 429:
        return CallErrorKind.rate_limit
    if status in (401, 403):
        return CallErrorKind.auth
    if status == 408:
        return CallErrorKind.timeout
    if status == 409 or status >= 500:
        return CallErrorKind.server
    return CallErrorKind.bad_request


def retry_after_seconds(headers: Mapping[str, str] | None, now: float | None = None
                        ) -> float | None:
    """Seconds to wait from ``retry-after-ms``, ``Retry-After`` (seconds or an HTTP date)."""
    if not headers:
        return None
    lower = {k.lower(): v for k, v in headers.items()}
    raw_ms = lower.get("retry-after-ms")
    if raw_ms is not None:
        try:
            return max(0.0, float(raw_ms) / 1000.0)
        except ValueError:
            pass
    raw = lower.get("retry-after")
    if raw is None:
        return None
    try:
        return max(0.0, float(raw))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(raw)
    except (TypeError, ValueError):
        return None
    return max(0.0, when.timestamp() - (time.time() if now is None else now))


@dataclass(frozen=True)
class RetryPolicy:
    max_attempts: int = 6           # HTTP attempts per call, the first included
    base_delay_s: float = 1.0       # backoff: base · 2^(attempt-1), with ±25 % jitter
    max_delay_s: float = 60.0
    max_retry_after_s: float = 600.0  # a longer Retry-After is not waited for: the call fails
    timeout_s: float = 600.0        # per HTTP attempt

    @classmethod
    def from_cfg(cls, cfg: Any) -> "RetryPolicy":
        retries = cfg.get("retries") or {}
        return cls(max_attempts=int(retries.get("max_attempts", cls.max_attempts)),
                   base_delay_s=float(retries.get("base_delay_s", cls.base_delay_s)),
                   max_delay_s=float(retries.get("max_delay_s", cls.max_delay_s)),
                   max_retry_after_s=float(retries.get("max_retry_after_s",
                                                       cls.max_retry_after_s)),
                   timeout_s=float(cfg.get("timeout_s", cls.timeout_s)))

    def backoff(self, attempt: int, rng: random.Random) -> float:
        delay = min(self.max_delay_s, self.base_delay_s * 2 ** (attempt - 1))
        return delay * (0.75 + 0.5 * rng.random())


class AdaptiveLimiter:
    """At most `limit` calls in flight; the limit adapts (AIMD) between 1 and `maximum`."""

    def __init__(self, initial: int = 4, maximum: int = 16):
        self.maximum = max(1, int(maximum))
        self.limit = max(1, min(int(initial), self.maximum))
        self.in_flight = 0
        self.peak_in_flight = 0
        self.throttles = 0
        self._successes = 0
        self._last_cut = 0.0
        self._cond: asyncio.Condition | None = None

    def _condition(self) -> asyncio.Condition:
        if self._cond is None:
            self._cond = asyncio.Condition()
        return self._cond

    @asynccontextmanager
    async def slot(self) -> AsyncIterator["AdaptiveLimiter"]:
        cond = self._condition()
        async with cond:
            await cond.wait_for(lambda: self.in_flight < self.limit)
            self.in_flight += 1
            self.peak_in_flight = max(self.peak_in_flight, self.in_flight)
        try:
            yield self
        finally:
            async with cond:
                self.in_flight -= 1
                cond.notify_all()

    def throttled(self) -> None:
        """A 429: halve the limit (at most once a second, so one burst counts once)."""
        self.throttles += 1
        self._successes = 0
        now = time.monotonic()
        if now - self._last_cut >= 1.0:
            self.limit = max(1, self.limit // 2)
            self._last_cut = now

    def succeeded(self) -> None:
        """A success: after `limit` successes in a row the limit grows by one."""
        self._successes += 1
        if self._successes >= self.limit and self.limit < self.maximum:
            self.limit += 1
            self._successes = 0
            if self._cond is not None:
                cond = self._cond

                async def wake() -> None:
                    async with cond:
                        cond.notify_all()

                asyncio.get_running_loop().create_task(wake())

    def stats(self) -> dict[str, int]:
        return {"limit": self.limit, "maximum": self.maximum,
                "peak_in_flight": self.peak_in_flight, "throttles": self.throttles}


_LIMITERS: dict[tuple[str, int], AdaptiveLimiter] = {}


def limiter_for(endpoint: str, initial: int, maximum: int) -> AdaptiveLimiter:
    """The process-wide limiter of one provider endpoint (per event loop)."""
    key = (endpoint, id(asyncio.get_running_loop()))
    if key not in _LIMITERS:
        _LIMITERS[key] = AdaptiveLimiter(initial, maximum)
    return _LIMITERS[key]


def limiter_stats() -> dict[str, dict[str, int]]:
    return {endpoint: lim.stats() for (endpoint, _), lim in _LIMITERS.items()}


async def call_with_retries(attempt: Callable[[], Awaitable[T]], policy: RetryPolicy,
                            limiter: AdaptiveLimiter, rng: random.Random | None = None,
                            sleep: Callable[[float], Awaitable[Any]] = asyncio.sleep
                            ) -> tuple[T, int]:
    """``await attempt()`` under the limiter, retried per ``policy``; returns (result, attempts).

    Raises the last `CallError` when retrying cannot help or the attempts are spent.
    """
    rng = rng or random.Random()
    for n in range(1, policy.max_attempts + 1):
        try:
            async with limiter.slot():
                try:
                    result = await asyncio.wait_for(attempt(), timeout=policy.timeout_s)
                except asyncio.TimeoutError:
                    raise CallError(CallErrorKind.timeout,
                                    f"no reply within {policy.timeout_s:g} s") from None
            limiter.succeeded()
            return result, n
        except CallError as exc:
            if exc.kind is CallErrorKind.rate_limit:
                limiter.throttled()
            if not exc.retryable or n == policy.max_attempts:
                exc.attempts = n  # type: ignore[attr-defined]
                raise
            delay = exc.retry_after_s
            if delay is not None and delay > policy.max_retry_after_s:
                long = CallError(exc.kind, f"{exc} (Retry-After {delay:g} s exceeds "
                                 f"{policy.max_retry_after_s:g} s)", exc.status, delay)
                long.attempts = n  # type: ignore[attr-defined]
                raise long from exc
            await sleep(policy.backoff(n, rng) if delay is None else delay)
    raise AssertionError("unreachable")
