"""Unit tests of the provider-facing plumbing: retries and concurrency (`calls`), money and the
cost cap (`usage`), judge-reply parsing (`judge`), validation of a model's scene spec S
(`reply_spec`) and the versioned prompt templates (`prompts`).

Everything here is in-process and fast: delays are milliseconds, sleeps are recorded instead of
waited for where the test is about the delay's value, and no provider is contacted.
"""

from __future__ import annotations

import asyncio
import copy
import email.utils
import hashlib
import io
import json
import random
import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from visphy_core.api.judge import parse_verdict, uniform_indices
from visphy_core.api.scene import Scene
from visphy_core.calls.prompts import build as prompts
from visphy_core.calls.retry import (
    RETRYABLE,
    AdaptiveLimiter,
    CallError,
    CallErrorKind,
    RetryPolicy,
    call_with_retries,
    kind_for_status,
    retry_after_seconds,
)
from visphy_core.calls.usage import CallRecord, CostCapReached, Price, UsageLedger
from visphy_core.infra.video import ClipInfo
from visphy_core.spec.reply_spec import spec_problems

PROMPTS_DIR = Path(prompts.__file__).parent


class FixedRandom(random.Random):
    """A `random.Random` whose `random()` always returns one value (to pin the jitter)."""

    def __init__(self, value: float):
        super().__init__(0)
        self.value = value

    def random(self) -> float:  # noqa: D401 - stdlib signature
        return self.value


# =============================================================================================
# calls.retry_after_seconds
# =============================================================================================
class TestRetryAfterSeconds:
    """``Retry-After`` as seconds or an HTTP date, ``retry-after-ms``, and junk."""

    @pytest.mark.parametrize("raw, expected", [("120", 120.0), ("0", 0.0), ("1.5", 1.5),
                                               (" 7 ", 7.0)])
    def test_delta_seconds(self, raw, expected):
        assert retry_after_seconds({"Retry-After": raw}) == expected

    @pytest.mark.parametrize("name", ["retry-after", "RETRY-AFTER", "Retry-After"])
    def test_header_name_is_case_insensitive(self, name):
        assert retry_after_seconds({name: "3"}) == 3.0

    def test_negative_seconds_clamp_to_zero(self):
        assert retry_after_seconds({"Retry-After": "-5"}) == 0.0

    def test_http_date_relative_to_given_now(self):
        now = 1_700_000_000.0
        header = email.utils.formatdate(now + 30, usegmt=True)  # "Tue, 14 Nov 2023 ... GMT"
        assert retry_after_seconds({"Retry-After": header}, now=now) == pytest.approx(30.0)

    def test_http_date_in_the_past_is_zero(self):
        now = 1_700_000_000.0
        header = email.utils.formatdate(now - 3600, usegmt=True)
        assert retry_after_seconds({"Retry-After": header}, now=now) == 0.0

    def test_http_date_defaults_to_wall_clock(self):
        header = email.utils.formatdate(time.time() + 60, usegmt=True)
        # formatdate drops fractions of a second; allow for that and a slow machine
        assert 57.0 <= retry_after_seconds({"Retry-After": header}) <= 60.0

    def test_retry_after_ms(self):
        assert retry_after_seconds({"retry-after-ms": "250"}) == pytest.approx(0.25)

    def test_retry_after_ms_takes_precedence(self):
        headers = {"Retry-After": "10", "Retry-After-Ms": "1500"}
        assert retry_after_seconds(headers) == pytest.approx(1.5)

    def test_garbage_ms_falls_back_to_retry_after(self):
        assert retry_after_seconds({"retry-after-ms": "soon", "retry-after": "4"}) == 4.0

    def test_negative_ms_clamps_to_zero(self):
        assert retry_after_seconds({"retry-after-ms": "-100"}) == 0.0

    @pytest.mark.parametrize("headers", [None, {}, {"Content-Type": "application/json"}])
    def test_missing(self, headers):
        assert retry_after_seconds(headers) is None

    @pytest.mark.parametrize("raw", ["soon", "", "Wed, 99 Foo 2015",
                                     "Mon, 01 Jan 99999 00:00:00 GMT"])
    def test_garbage_is_none_not_an_exception(self, raw):
        assert retry_after_seconds({"Retry-After": raw}, now=0.0) is None


# =============================================================================================
# calls.kind_for_status / CallError
# =============================================================================================
class TestErrorKinds:
    """HTTP statuses map to kinds; only transient kinds are retryable."""

    @pytest.mark.parametrize("status, kind", [
        (429, CallErrorKind.rate_limit),
        (500, CallErrorKind.server), (502, CallErrorKind.server), (503, CallErrorKind.server),
        (504, CallErrorKind.server), (529, CallErrorKind.server), (409, CallErrorKind.server),
        (401, CallErrorKind.auth), (403, CallErrorKind.auth),
        (408, CallErrorKind.timeout),
        (400, CallErrorKind.bad_request), (404, CallErrorKind.bad_request),
        (413, CallErrorKind.bad_request), (422, CallErrorKind.bad_request),
    ])
    def test_kind_for_status(self, status, kind):
        assert kind_for_status(status) is kind

    @pytest.mark.parametrize("kind", list(CallErrorKind))
    def test_retryable(self, kind):
        expected = kind not in (CallErrorKind.auth, CallErrorKind.bad_request)
        assert CallError(kind, "x").retryable is expected
        assert (kind in RETRYABLE) is expected

    def test_kind_accepts_plain_string_and_describe_is_one_line(self):
        err = CallError("rate_limit", "too\n  many   requests", status=429, retry_after_s=2.0)
        assert err.kind is CallErrorKind.rate_limit
        assert err.describe() == "rate_limit HTTP 429: too many requests"
        assert CallError(CallErrorKind.timeout, "slow").describe() == "timeout: slow"


# =============================================================================================
# calls.RetryPolicy
# =============================================================================================
class TestRetryPolicy:
    """Exponential backoff with ±25 % jitter, capped at ``max_delay_s``."""

    def test_exponential_growth_then_cap_without_jitter(self):
        policy = RetryPolicy(base_delay_s=1.0, max_delay_s=60.0)
        mid = FixedRandom(0.5)  # jitter factor 0.75 + 0.5 * 0.5 = 1.0
        delays = [policy.backoff(n, mid) for n in range(1, 10)]
        assert delays == [1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 60.0, 60.0, 60.0]

    def test_jitter_bounds(self):
        policy = RetryPolicy(base_delay_s=0.2, max_delay_s=5.0)
        assert policy.backoff(3, FixedRandom(0.0)) == pytest.approx(0.8 * 0.75)
        assert policy.backoff(3, FixedRandom(0.999999)) == pytest.approx(0.8 * 1.25, rel=1e-5)
        rng = random.Random(1)
        for n in range(1, 12):
            nominal = min(5.0, 0.2 * 2 ** (n - 1))
            assert 0.75 * nominal <= policy.backoff(n, rng) < 1.25 * nominal

    def test_jitter_is_applied_after_the_cap(self):
        """The cap bounds the nominal delay; jitter may take one delay up to 1.25 × cap."""
        policy = RetryPolicy(base_delay_s=1.0, max_delay_s=10.0)
        assert policy.backoff(20, FixedRandom(0.0)) == pytest.approx(7.5)
        assert policy.backoff(20, FixedRandom(0.999999)) <= 12.5

    def test_from_cfg(self):
        policy = RetryPolicy.from_cfg({"retries": {"max_attempts": 3, "base_delay_s": 0.5,
                                                   "max_delay_s": 4, "max_retry_after_s": 9},
                                       "timeout_s": 12})
        assert policy == RetryPolicy(max_attempts=3, base_delay_s=0.5, max_delay_s=4.0,
                                     max_retry_after_s=9.0, timeout_s=12.0)
        assert RetryPolicy.from_cfg({}) == RetryPolicy()


# =============================================================================================
# calls.AdaptiveLimiter
# =============================================================================================
async def _run_tasks(limiter: AdaptiveLimiter, n: int, hold_s: float = 0.01) -> int:
    """Run ``n`` tasks through the limiter; return the most that were inside at once."""
    inside = 0
    peak = 0

    async def one() -> None:
        nonlocal inside, peak
        async with limiter.slot():
            inside += 1
            peak = max(peak, inside)
            await asyncio.sleep(hold_s)
            inside -= 1

    await asyncio.gather(*(one() for _ in range(n)))
    return peak


class TestAdaptiveLimiter:
    """AIMD between 1 and ``maximum``; the limit really bounds the calls in flight."""

    @pytest.mark.parametrize("initial, maximum, limit, cap", [
        (4, 16, 4, 16), (20, 8, 8, 8), (0, 5, 1, 5), (3, 0, 1, 1)])
    def test_initial_limit_is_clamped(self, initial, maximum, limit, cap):
        lim = AdaptiveLimiter(initial, maximum)
        assert (lim.limit, lim.maximum) == (limit, cap)

    def test_concurrency_is_bounded_by_the_limit(self):
        lim = AdaptiveLimiter(initial=3, maximum=3)
        peak = asyncio.run(_run_tasks(lim, 12))
        assert peak == 3
        assert lim.peak_in_flight == 3
        assert lim.in_flight == 0

    def test_throttle_halves_once_per_burst(self):
        lim = AdaptiveLimiter(initial=8, maximum=16)
        lim.throttled()
        assert lim.limit == 4
        lim.throttled()  # same burst (< 1 s later): counted, but no second cut
        assert lim.limit == 4
        assert lim.throttles == 2
        assert lim.stats() == {"limit": 4, "maximum": 16, "peak_in_flight": 0, "throttles": 2}

    def test_limit_never_below_one(self):
        lim = AdaptiveLimiter(initial=1, maximum=4)
        lim.throttled()
        assert lim.limit == 1

    def test_throttled_limit_bounds_concurrency(self):
        lim = AdaptiveLimiter(initial=4, maximum=4)
        lim.throttled()
        assert lim.limit == 2
        assert asyncio.run(_run_tasks(lim, 8)) == 2

    def test_additive_increase_after_limit_successes(self):
        lim = AdaptiveLimiter(initial=2, maximum=3)
        lim.succeeded()
        assert lim.limit == 2  # one success of the two needed
        lim.succeeded()
        assert lim.limit == 3
        for _ in range(10):
            lim.succeeded()
        assert lim.limit == 3  # never above the maximum

    def test_throttle_resets_the_success_run(self):
        lim = AdaptiveLimiter(initial=4, maximum=8)
        lim.succeeded()
        lim.throttled()  # limit 2, run of successes restarts
        lim.succeeded()
        assert lim.limit == 2
        lim.succeeded()
        assert lim.limit == 3

    def test_growth_wakes_a_waiting_task(self):
        """A waiter blocked at limit 1 gets in once a success raises the limit to 2."""

        async def scenario() -> tuple[bool, bool]:
            lim = AdaptiveLimiter(initial=1, maximum=2)
            release_a = asyncio.Event()
            b_entered = asyncio.Event()

            async def a() -> None:
                async with lim.slot():
                    await release_a.wait()

            async def b() -> None:
                async with lim.slot():
                    b_entered.set()

            ta = asyncio.create_task(a())
            await asyncio.sleep(0.01)
            tb = asyncio.create_task(b())
            await asyncio.sleep(0.01)
            blocked_before = not b_entered.is_set()
            lim.succeeded()  # 1 success at limit 1 -> limit 2, waiters notified
            try:
                await asyncio.wait_for(b_entered.wait(), timeout=1.0)
                entered = True
            except asyncio.TimeoutError:
                entered = False
            release_a.set()
            await asyncio.gather(ta, tb)
            return blocked_before, entered

        blocked_before, entered = asyncio.run(scenario())
        assert blocked_before
        assert entered


# =============================================================================================
# calls.call_with_retries
# =============================================================================================
class Flaky:
    """An attempt that raises the given errors in turn, then returns ``result``."""

    def __init__(self, errors: list[BaseException], result: object = "ok",
                 hang_s: float | None = None):
        self.errors = list(errors)
        self.result = result
        self.calls = 0
        self.hang_s = hang_s

    async def __call__(self) -> object:
        self.calls += 1
        if self.hang_s is not None and self.errors:
            self.errors.pop(0)
            await asyncio.sleep(self.hang_s)
        if self.errors:
            raise self.errors.pop(0)
        return self.result


def _retry(attempt, policy, limiter=None, rng=None):
    """Run `call_with_retries` with recorded (not waited) sleeps: (result|exc, sleeps)."""
    sleeps: list[float] = []

    async def record_sleep(delay: float) -> None:
        sleeps.append(delay)

    async def go():
        return await call_with_retries(attempt, policy, limiter or AdaptiveLimiter(4, 4),
                                       rng=rng, sleep=record_sleep)

    try:
        return asyncio.run(go()), sleeps
    except BaseException as exc:  # noqa: BLE001 - handed back to the test
        return exc, sleeps


FAST = RetryPolicy(max_attempts=4, base_delay_s=0.001, max_delay_s=0.004, timeout_s=5.0)


class TestCallWithRetries:
    """Transient errors are retried with backoff; permanent ones are raised at once."""

    @pytest.mark.parametrize("kind", sorted(RETRYABLE))
    def test_retries_a_transient_error_then_succeeds(self, kind):
        attempt = Flaky([CallError(kind, "transient"), CallError(kind, "transient")], "done")
        result, sleeps = _retry(attempt, FAST)
        assert result == ("done", 3)
        assert attempt.calls == 3
        assert len(sleeps) == 2

    def test_backoff_delays_between_attempts(self):
        policy = RetryPolicy(max_attempts=4, base_delay_s=0.1, max_delay_s=10.0)
        attempt = Flaky([CallError(CallErrorKind.server, "503")] * 3)
        result, sleeps = _retry(attempt, policy, rng=FixedRandom(0.5))
        assert result == ("ok", 4)
        assert sleeps == pytest.approx([0.1, 0.2, 0.4])

    def test_gives_up_after_max_attempts_with_the_last_kind(self):
        errors = [CallError(CallErrorKind.connection, "reset")] * 3 + [
            CallError(CallErrorKind.server, "502", status=502)] * 5
        attempt = Flaky(errors)
        exc, sleeps = _retry(attempt, FAST)
        assert isinstance(exc, CallError)
        assert exc.kind is CallErrorKind.server and exc.status == 502
        assert exc.attempts == FAST.max_attempts
        assert attempt.calls == FAST.max_attempts
        assert len(sleeps) == FAST.max_attempts - 1

    @pytest.mark.parametrize("kind", [CallErrorKind.auth, CallErrorKind.bad_request])
    def test_permanent_error_is_not_retried(self, kind):
        attempt = Flaky([CallError(kind, "no")] * 3)
        exc, sleeps = _retry(attempt, FAST)
        assert isinstance(exc, CallError) and exc.kind is kind
        assert exc.attempts == 1
        assert attempt.calls == 1 and sleeps == []

    def test_foreign_exception_propagates_without_retry(self):
        attempt = Flaky([KeyError("bug in the adapter")] * 3)
        exc, sleeps = _retry(attempt, FAST)
        assert isinstance(exc, KeyError)
        assert attempt.calls == 1 and sleeps == []

    def test_retry_after_is_honoured_instead_of_backoff(self):
        attempt = Flaky([CallError(CallErrorKind.rate_limit, "429", 429, retry_after_s=0.0125)])
        result, sleeps = _retry(attempt, FAST)
        assert result == ("ok", 2)
        assert sleeps == [0.0125]

    def test_too_long_retry_after_fails_without_waiting(self):
        policy = RetryPolicy(max_attempts=5, base_delay_s=0.001, max_retry_after_s=30.0)
        attempt = Flaky([CallError(CallErrorKind.rate_limit, "slow down", 429,
                                   retry_after_s=3600.0)])
        exc, sleeps = _retry(attempt, policy)
        assert isinstance(exc, CallError)
        assert exc.kind is CallErrorKind.rate_limit and exc.status == 429
        assert "Retry-After" in str(exc)
        assert attempt.calls == 1 and sleeps == []

    def test_too_long_retry_after_reports_the_attempts_made(self):
        policy = RetryPolicy(max_attempts=5, base_delay_s=0.001, max_retry_after_s=30.0)
        attempt = Flaky([CallError(CallErrorKind.server, "503", 503)] * 2 + [
            CallError(CallErrorKind.rate_limit, "slow down", 429, retry_after_s=3600.0)])
        exc, _ = _retry(attempt, policy)
        assert isinstance(exc, CallError) and attempt.calls == 3
        assert getattr(exc, "attempts", None) == 3

    def test_per_call_timeout_is_retried(self):
        policy = RetryPolicy(max_attempts=3, base_delay_s=0.001, timeout_s=0.05)
        attempt = Flaky([None], "late but fine", hang_s=5.0)  # first attempt hangs
        start = time.perf_counter()
        result, sleeps = _retry(attempt, policy)
        assert result == ("late but fine", 2)
        assert time.perf_counter() - start < 2.0
        assert len(sleeps) == 1

    def test_per_call_timeout_exhausted_is_a_timeout_error(self):
        policy = RetryPolicy(max_attempts=2, base_delay_s=0.001, timeout_s=0.03)
        attempt = Flaky([None, None], hang_s=5.0)
        exc, _ = _retry(attempt, policy)
        assert isinstance(exc, CallError)
        assert exc.kind is CallErrorKind.timeout and exc.attempts == 2

    def test_rate_limit_throttles_the_limiter_and_slots_are_released(self):
        lim = AdaptiveLimiter(initial=4, maximum=8)
        attempt = Flaky([CallError(CallErrorKind.rate_limit, "429", 429)])
        result, _ = _retry(attempt, FAST, limiter=lim)
        assert result == ("ok", 2)
        assert lim.throttles == 1 and lim.limit == 2
        assert lim.in_flight == 0

    def test_successes_grow_the_limiter(self):
        lim = AdaptiveLimiter(initial=1, maximum=3)

        async def go() -> None:
            for _ in range(3):  # 1 success at limit 1 -> 2; 2 successes at limit 2 -> 3
                await call_with_retries(Flaky([]), FAST, lim)

        asyncio.run(go())
        assert lim.limit == 3 and lim.in_flight == 0

    def test_concurrent_calls_respect_the_limiter(self):
        lim = AdaptiveLimiter(initial=2, maximum=2)
        inside = 0
        peak = 0

        async def attempt() -> str:
            nonlocal inside, peak
            inside += 1
            peak = max(peak, inside)
            await asyncio.sleep(0.005)
            inside -= 1
            return "ok"

        async def go():
            return await asyncio.gather(*(call_with_retries(attempt, FAST, lim)
                                          for _ in range(8)))

        results = asyncio.run(go())
        assert results == [("ok", 1)] * 8
        assert peak == 2


# =============================================================================================
# usage.Price
# =============================================================================================
class TestPrice:
    """USD per million tokens; cached input at its own price; reasoning is in output."""

    def test_input_and_output(self):
        price = Price(input_usd_per_mtok=2.0, output_usd_per_mtok=8.0)
        # 1000 × $2/M + 500 × $8/M = $0.002 + $0.004
        assert price.cost({"input_tokens": 1000, "output_tokens": 500}) == pytest.approx(0.006)

    def test_cached_input_at_its_own_price(self):
        price = Price(2.0, 8.0, cached_input_usd_per_mtok=0.5)
        usage = {"input_tokens": 1000, "cached_input_tokens": 400, "output_tokens": 0}
        assert price.cost(usage) == pytest.approx((600 * 2.0 + 400 * 0.5) / 1e6)

    def test_cached_input_without_a_cached_price_is_billed_as_input(self):
        price = Price(2.0, 8.0)
        usage = {"input_tokens": 1000, "cached_input_tokens": 400}
        assert price.cost(usage) == pytest.approx(1000 * 2.0 / 1e6)

    def test_cached_never_exceeds_input(self):
        price = Price(2.0, 8.0, cached_input_usd_per_mtok=0.0)
        assert price.cost({"input_tokens": 100, "cached_input_tokens": 500}) == 0.0

    def test_reasoning_tokens_are_not_billed_twice(self):
        price = Price(1.0, 10.0)
        usage = {"input_tokens": 0, "output_tokens": 300, "reasoning_tokens": 200}
        assert price.cost(usage) == pytest.approx(300 * 10.0 / 1e6)

    def test_empty_usage_is_free(self):
        assert Price(3.0, 15.0).cost({}) == 0.0

    def test_from_cfg(self):
        assert Price.from_cfg({"input_usd_per_mtok": "1.25", "output_usd_per_mtok": 10,
                               "cached_input_usd_per_mtok": 0.125}) == Price(1.25, 10.0, 0.125)
        assert Price.from_cfg({"input_usd_per_mtok": 3, "output_usd_per_mtok": 15}) \
            == Price(3.0, 15.0, None)

    @pytest.mark.parametrize("cfg", [None, {}, {"input_usd_per_mtok": 1.0},
                                     {"input_usd_per_mtok": None, "output_usd_per_mtok": 2.0}])
    def test_from_cfg_without_a_full_price(self, cfg):
        assert Price.from_cfg(cfg) is None


# =============================================================================================
# usage.UsageLedger
# =============================================================================================
def _rec(stage="generate", cost=0.01, cached=False, ok=True, scene="task00000_000", **usage):
    return CallRecord(stage=stage, scene_id=scene, caller="m", provider="p", model_id="mid",
                      cached=cached, ok=ok, cost_usd=cost, usage=dict(usage))


class TestUsageLedger:
    """calls.jsonl, per-stage totals, reservations and the cost cap."""

    def test_record_writes_one_json_line_per_call(self, tmp_path):
        path = tmp_path / "calls.jsonl"
        ledger = UsageLedger(path)
        ledger.record(_rec(cost=0.5, input_tokens=10, output_tokens=3))
        ledger.record(_rec(stage="judge", cost=None, ok=False))
        lines = path.read_text().splitlines()
        assert len(lines) == 2
        first, second = (json.loads(line) for line in lines)
        assert first["stage"] == "generate" and first["cost_usd"] == 0.5
        assert first["usage"] == {"input_tokens": 10, "output_tokens": 3}
        assert second["stage"] == "judge" and second["ok"] is False
        assert CallRecord(**first) == _rec(cost=0.5, input_tokens=10, output_tokens=3)

    def test_totals_per_stage_and_all(self):
        ledger = UsageLedger()
        ledger.record(_rec("judge", 0.25, input_tokens=100, output_tokens=10))
        ledger.record(_rec("generate", 1.0, input_tokens=1000, output_tokens=200,
                           cached_input_tokens=50, reasoning_tokens=20))
        ledger.record(_rec("generate", 2.0, input_tokens=500, output_tokens=100))
        ledger.record(_rec("generate", 4.0, cached=True, input_tokens=999))  # cache hit
        ledger.record(_rec("generate", None, ok=False))                     # failed call
        ledger.record(_rec("reference", None))                              # unpriced success
        totals = ledger.totals()
        assert list(totals) == ["generate", "judge", "reference", "all"]
        gen = totals["generate"]
        assert gen["calls"] == 3 and gen["cache_hits"] == 1 and gen["errors"] == 1
        assert gen["cost_usd"] == pytest.approx(3.0)
        assert gen["cost_usd_incl_cached"] == pytest.approx(7.0)
        assert gen["input_tokens"] == 1500  # the cache hit's tokens are not this run's
        assert gen["output_tokens"] == 300
        assert gen["cached_input_tokens"] == 50 and gen["reasoning_tokens"] == 20
        assert gen["unpriced_calls"] == 0  # a failed call is not an unpriced one
        assert totals["reference"]["unpriced_calls"] == 1
        every = totals["all"]
        assert every["calls"] == 5 and every["cache_hits"] == 1 and every["errors"] == 1
        assert every["cost_usd"] == pytest.approx(3.25)
        assert every["input_tokens"] == 1600
        assert ledger.spent_usd == pytest.approx(3.25)

    def test_unknown_stage_is_listed_after_the_known_ones(self):
        ledger = UsageLedger()
        ledger.record(_rec("zeta"))
        ledger.record(_rec("alpha"))
        ledger.record(_rec("repair"))
        # known stages in pipeline order, then the rest ("all" included) alphabetically
        assert list(ledger.totals()) == ["repair", "all", "alpha", "zeta"]

    def test_empty_ledger_has_no_totals(self):
        assert UsageLedger().totals() == {}
        assert UsageLedger().spent_usd == 0.0

    def test_no_cap_never_refuses(self):
        ledger = UsageLedger(cap_usd=None)
        ledger.record(_rec(cost=1e6))
        tickets = [ledger.reserve() for _ in range(5)]
        assert len(set(tickets)) == 5
        assert not ledger.stopped_by_cap

    def test_cap_refuses_a_call_once_spent_reaches_it(self):
        ledger = UsageLedger(cap_usd=1.0)
        ledger.record(_rec(cost=0.4))
        ledger.release(ledger.reserve())
        ledger.record(_rec(cost=0.6))  # spent 1.0: exactly the cap
        with pytest.raises(CostCapReached) as info:
            ledger.reserve()
        assert info.value.cap_usd == 1.0
        assert info.value.spent_usd == pytest.approx(1.0)
        assert "$1.00" in str(info.value)
        assert ledger.stopped_by_cap

    def test_calls_in_flight_count_against_the_cap(self):
        ledger = UsageLedger(cap_usd=1.0)
        ledger.record(_rec(cost=0.3))          # spent 0.3; expected cost of a call 0.3
        t1 = ledger.reserve()                  # committed 0.3 -> allowed, reserves 0.3
        t2 = ledger.reserve()                  # committed 0.6 -> allowed
        t3 = ledger.reserve()                  # committed 0.9 -> allowed
        with pytest.raises(CostCapReached):
            ledger.reserve()                   # committed 1.2 >= 1.0
        ledger.release(t3)                     # a call that was never sent frees its share
        t4 = ledger.reserve()
        assert len({t1, t2, t3, t4}) == 4
        ledger.record(_rec(cost=0.3), ticket=t1)  # recording settles the reservation
        ledger.release(t2)
        ledger.release(t4)
        ledger.release(t4)                     # releasing twice is harmless
        assert ledger.reserve() > t4           # spent 0.6 -> allowed

    def test_before_the_first_paid_call_a_call_counts_at_its_bound(self):
        """Nothing paid yet: calls in flight count at ``first_call_usd``, so the first batch
        cannot overshoot a small cap; the first paid call's cost then takes over."""
        ledger = UsageLedger(cap_usd=0.05, first_call_usd=0.02)
        tickets = [ledger.reserve(), ledger.reserve(), ledger.reserve()]  # 0, 0.02, 0.04
        with pytest.raises(CostCapReached):
            ledger.reserve()                                    # 0.06 >= 0.05
        ledger.record(_rec(cost=0.001), ticket=tickets[0])     # paid: 0.001 a call
        assert ledger.reserve() > tickets[-1]                  # 0.001 + 0.04 + 0.001 < 0.05

    def test_a_call_cost_bound_from_the_model_config(self):
        from visphy_core.calls.usage import PROMPT_TOKENS_BOUND, call_cost_bound

        cfg = {"price": {"input_usd_per_mtok": 2.0, "output_usd_per_mtok": 10.0},
               "max_output_tokens": 1000}
        assert call_cost_bound(cfg) == pytest.approx((PROMPT_TOKENS_BOUND * 2 + 1000 * 10) / 1e6)
        assert call_cost_bound({"price": None, "max_output_tokens": 1000}) == 0.0
        assert call_cost_bound({"price": {"usd_per_second": 0.4}}) == 0.0
        assert call_cost_bound(None) == 0.0

    def test_cache_hits_do_not_count_against_the_cap(self):
        ledger = UsageLedger(cap_usd=1.0)
        ledger.record(_rec(cost=5.0, cached=True))
        assert ledger.spent_usd == 0.0
        ledger.reserve()

    def test_unpriced_calls_cannot_trip_the_cap(self):
        """The ledger cannot price calls without a price: it never stops them (the run refuses
        a cost cap with an unpriced model before any call, in `run_setup._check_ready`)."""
        ledger = UsageLedger(cap_usd=0.01)
        for _ in range(20):
            ledger.record(_rec(cost=None, input_tokens=10_000), ticket=ledger.reserve())
        assert ledger.spent_usd == 0.0
        assert ledger.totals()["all"]["unpriced_calls"] == 20
        assert not ledger.stopped_by_cap

    def test_restart_reads_the_ledger_back(self, tmp_path):
        path = tmp_path / "calls.jsonl"
        first = UsageLedger(path, cap_usd=1.0)
        first.record(_rec("generate", 0.5, input_tokens=100))
        first.record(_rec("judge", 0.25, output_tokens=7))
        first.record(_rec("generate", 9.0, cached=True))
        again = UsageLedger(path, cap_usd=1.0)
        assert again.totals() == first.totals()
        assert again.spent_usd == pytest.approx(0.75)
        # the cap covers the whole run: 0.75 spent + 0.375 expected in flight crosses $1
        again.reserve()
        with pytest.raises(CostCapReached):
            again.reserve()

    def test_restart_skips_a_half_written_last_line(self, tmp_path):
        path = tmp_path / "calls.jsonl"
        UsageLedger(path).record(_rec(cost=0.5))
        with open(path, "a") as fh:
            fh.write('{"stage": "generate", "scene_id": "task0')  # killed mid-write
        again = UsageLedger(path)
        assert again.totals()["all"]["calls"] == 1
        assert again.spent_usd == pytest.approx(0.5)

    def test_records_after_a_half_written_line_survive_the_next_restart(self, tmp_path):
        path = tmp_path / "calls.jsonl"
        UsageLedger(path).record(_rec(cost=0.5))
        with open(path, "a") as fh:
            fh.write('{"stage": "generate", "scene_id": "task0')  # killed mid-write
        resumed = UsageLedger(path)
        resumed.record(_rec(cost=0.25))
        assert resumed.spent_usd == pytest.approx(0.75)
        third = UsageLedger(path)
        assert third.spent_usd == pytest.approx(0.75)

    def test_concurrent_records_are_all_written(self, tmp_path):
        path = tmp_path / "calls.jsonl"
        ledger = UsageLedger(path)

        def worker(i: int) -> None:
            for j in range(25):
                ledger.record(_rec(cost=0.001, scene=f"task{i:05d}_{j:03d}"))

        threads = [threading.Thread(target=worker, args=(i,)) for i in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        rows = [json.loads(line) for line in path.read_text().splitlines()]
        assert len(rows) == 150
        assert len({r["scene_id"] for r in rows}) == 150
        assert UsageLedger(path).totals()["all"]["calls"] == 150


# =============================================================================================
# judge.parse_verdict / judge.uniform_indices
# =============================================================================================
class TestParseVerdict:
    """JSON bare, fenced or in prose; 1–10 only; invalid verdicts carry an error."""

    @pytest.mark.parametrize("text, score, justification", [
        ('{"score": 7, "justification": "close"}', 7.0, "close"),
        ('```json\n{"score": 8, "justification": "good"}\n```', 8.0, "good"),
        ('```\n{"score": 3, "justification": "partial"}\n```', 3.0, "partial"),
        ('Here is my verdict:\n{"score": 5, "justification": "meh"}\nThanks!', 5.0, "meh"),
        ('Thinking {not json} first.\n```json\n{"score": 6, "justification": "ok"}\n```',
         6.0, "ok"),
        ('{"score": "7/10", "justification": "x"}', 7.0, "x"),
        ('{"score": "7", "justification": "x"}', 7.0, "x"),
        ('{"score": " 9 / 10 ", "justification": "x"}', 9.0, "x"),
        ('{"score": 6.5, "justification": "x"}', 6.5, "x"),
        ('{"score": "6.5", "justification": "x"}', 6.5, "x"),
        ('{"score": 1}', 1.0, ""),
        ('{"score": 10, "reason": "perfect"}', 10.0, "perfect"),
        ('{"score": 4, "justification": "  padded  "}', 4.0, "padded"),
        ('{"other": 1} then {"score": 2, "justification": "second object"}', 2.0,
         "second object"),
    ])
    def test_valid(self, text, score, justification):
        assert parse_verdict(text) == (score, justification, None)

    @pytest.mark.parametrize("text", [
        '{"score": 0, "justification": "x"}', '{"score": 11, "justification": "x"}',
        '{"score": -3, "justification": "x"}', '{"score": 10.5}', '{"score": "11/10"}',
        '{"score": "0/10"}', '{"score": NaN}', '{"score": Infinity}'])
    def test_out_of_range_is_invalid(self, text):
        score, _, error = parse_verdict(text)
        assert score is None
        assert error and "outside" in error

    @pytest.mark.parametrize("text", [
        '{"score": "seven"}', '{"score": null}', '{"score": true}', '{"score": [7]}',
        '{"score": "8/100"}', '{"score": "7 out of 10"}'])
    def test_non_numeric_score_is_invalid(self, text):
        score, _, error = parse_verdict(text)
        assert score is None
        assert error and "not a number" in error

    @pytest.mark.parametrize("text", [
        '{"justification": "forgot the score"}', "The score is 7/10.", "7",
        '{"verdict": {"score": 7}}', '["score", 7]', "{score: 7}"])
    def test_missing_score_or_no_json_is_invalid(self, text):
        score, _, error = parse_verdict(text)
        assert score is None
        assert error == "no JSON object with a score in the reply"

    @pytest.mark.parametrize("text", ["", "   \n\t "])
    def test_empty_is_invalid(self, text):
        assert parse_verdict(text) == (None, "", "empty reply")

    def test_justification_kept_when_score_invalid(self):
        assert parse_verdict('{"score": 12, "justification": "great"}')[1] == "great"

    def test_custom_score_range(self):
        assert parse_verdict('{"score": 0}', score_range=(0.0, 5.0))[0] == 0.0
        assert parse_verdict('{"score": 6}', score_range=(0.0, 5.0))[0] is None


class TestUniformIndices:
    """k indices spread over n frames: sorted, distinct, first and last included."""

    @pytest.mark.parametrize("n, k, expected", [
        (10, 2, [0, 9]), (10, 4, [0, 3, 6, 9]), (5, 3, [0, 2, 4]), (101, 5, [0, 25, 50, 75, 100]),
        (10, 1, [0]), (1, 1, [0]), (1, 8, [0]), (4, 4, [0, 1, 2, 3]), (4, 9, [0, 1, 2, 3]),
        (0, 3, []), (-2, 3, []), (7, 0, [0])])
    def test_values(self, n, k, expected):
        assert uniform_indices(n, k) == expected

    @pytest.mark.parametrize("n", [2, 3, 7, 16, 75, 76, 300])
    @pytest.mark.parametrize("k", [2, 3, 5, 8, 16, 50])
    def test_properties(self, n, k):
        idx = uniform_indices(n, k)
        assert len(idx) == min(k, n)
        assert idx == sorted(set(idx))
        assert idx[0] == 0 and idx[-1] == n - 1
        gaps = np.diff(idx)
        if len(gaps):  # evenly spread: gaps differ by at most one frame
            assert gaps.max() - gaps.min() <= 1


# =============================================================================================
# reply_spec.spec_problems
# =============================================================================================
VALID_S_2D = {
    "schema": "visphy-scene/1",
    "dim": "2d",
    "world": {"gravity_m_s2": [0.0, -9.8], "units": {"px_per_m": 6.0}},
    "bodies": [
        {"id": "ball", "category": "circle", "dynamic": True, "color_rgb": [243, 79, 70],
         "shape": {"type": "circle", "radius_px": 12.5},
         "pose": {"x_px": 100, "y_px": 400, "angle_rad": 0.0},
         "velocity": {"vx_px_s": 5.0, "vy_px_s": 0.0, "omega_rad_s": 0.0},
         "material": {"density_kg_m2": 0.25, "friction": 0.5, "restitution": 0.2}},
        {"id": "ramp", "category": "line", "dynamic": False, "color_rgb": [0, 0, 0],
         "shape": {"type": "box", "length_px": 200, "thickness_px": 10},
         "pose": {"x_px": 256, "y_px": 100, "angle_rad": 0.3}},
        {"id": "wedge", "category": "triangle", "dynamic": False, "color_rgb": [0, 0, 255],
         "shape": {"type": "polygon", "vertices_px": [[0, 0], [30, 0], [0, 30]]},
         "pose": {"x_px": 50, "y_px": 50, "angle_rad": 0}},
        {"id": "jar", "category": "u_shape", "dynamic": False, "color_rgb": [0, 128, 0],
         "shape": {"type": "compound", "parts_px": [[[0, 0], [10, 0], [10, 10]]]},
         "pose": {"x_px": 300, "y_px": 50, "angle_rad": 0}},
    ],
    "contacts": {"default": {"friction": 0.5, "restitution": 0.2},
                 "pairs": [{"a": "ball", "b": "ramp", "friction": 0.1, "restitution": 0.9}]},
}

VALID_S_3D = {
    "schema": "visphy-scene/1",
    "dim": "3d",
    "world": {"gravity_m_s2": [0.0, -9.82, 0.0]},
    "bodies": [
        {"id": "ball", "category": "circle", "dynamic": True, "color_rgb": [243, 79, 70],
         "shape": {"type": "sphere", "radius_m": 0.2},
         "pose": {"position_m": [0, 1, 0], "quat": [0, 0, 0, 1]},
         "velocity": {"linear_m_s": [1, 0, 0], "angular_rad_s": [0, 0, 0]},
         "material": {"mass_kg": 1.0, "friction": 0.3, "restitution": 0.5}},
        {"id": "floor", "category": "rectangle", "dynamic": False, "color_rgb": [200, 200, 200],
         "shape": {"type": "box", "size_m": [10, 0.1, 10]},
         "pose": {"position_m": [0, -0.05, 0], "quat": [0, 0, 0, 1]}},
        {"id": "slope", "category": "triangle", "dynamic": False, "color_rgb": [0, 0, 255],
         "shape": {"type": "wedge", "length_m": 2, "height_m": 1, "width_m": 1},
         "pose": {"position_m": [2, 0.3, 0], "quat": [0, 0, 0, 1]}},
        {"id": "dumbbell", "category": "composite_shape", "dynamic": True,
         "color_rgb": [9, 9, 9],
         "shape": {"type": "compound", "parts": [
             {"shape": {"type": "sphere", "radius_m": 0.1}, "offset_m": [-0.2, 0, 0],
              "quat": [0, 0, 0, 1]},
             {"shape": {"type": "box", "size_m": [0.4, 0.05, 0.05]}, "offset_m": [0, 0, 0],
              "quat": [0, 0, 0, 1]}]},
         "pose": {"position_m": [-1, 0.5, 0], "quat": [0, 0, 0, 1]},
         "velocity": {"linear_m_s": [0, 0, 0], "angular_rad_s": [0, 1, 0]},
         "material": {"density_kg_m3": 500, "friction": 0.3, "restitution": 0.1}},
    ],
    "contacts": {"default": {"friction": 0.3, "restitution": 0.2},
                 "pairs": [{"a": "ball", "b": "floor", "friction": 0.4, "restitution": 0.6}]},
}


def _mutated(spec: dict, edit) -> dict:
    out = copy.deepcopy(spec)
    edit(out)
    return out


class TestSpecProblems:
    """A valid S has no problems; an invalid one gets listed problems, never an exception."""

    def test_valid_2d(self):
        assert spec_problems(VALID_S_2D, "2d") == []

    def test_valid_3d(self):
        assert spec_problems(VALID_S_3D, "3d") == []

    def test_minimal_s_is_valid(self):
        """Only world.gravity and one body are required of a model."""
        minimal = {"world": {"gravity_m_s2": [0, -9.8]}, "bodies": [VALID_S_2D["bodies"][1]]}
        assert spec_problems(minimal, "2d") == []

    def test_dim_selects_the_schema(self):
        assert spec_problems(VALID_S_3D, "2d") != []
        assert spec_problems(VALID_S_2D, "3d") != []

    @pytest.mark.parametrize("spec, kind", [
        ([], "list"), ("{}", "str"), (None, "NoneType"), (7, "int")])
    def test_non_dict(self, spec, kind):
        assert spec_problems(spec, "2d") == [f"$: S is a {kind}, not a JSON object"]

    @pytest.mark.parametrize("dim, base, edit, where", [
        ("2d", VALID_S_2D, lambda s: s.pop("bodies"), "$: "),
        ("2d", VALID_S_2D, lambda s: s["world"].pop("gravity_m_s2"), "$.world: "),
        ("2d", VALID_S_2D, lambda s: s.__setitem__("bodies", []), "$.bodies: "),
        ("2d", VALID_S_2D, lambda s: s["world"].__setitem__("gravity_m_s2", "down"),
         "$.world.gravity_m_s2: "),
        ("2d", VALID_S_2D, lambda s: s["world"].__setitem__("gravity_m_s2", [0, -9.8, 0]),
         "$.world.gravity_m_s2: "),
        ("2d", VALID_S_2D, lambda s: s["bodies"][0]["shape"].__setitem__("radius_px", "big"),
         "$.bodies[0].shape.radius_px: "),
        ("2d", VALID_S_2D, lambda s: s["bodies"][0]["shape"].__setitem__("radius_px", -1),
         "$.bodies[0].shape.radius_px: "),
        ("2d", VALID_S_2D, lambda s: s["bodies"][0].pop("velocity"), "$.bodies[0]: "),
        ("2d", VALID_S_2D, lambda s: s["bodies"][1].__setitem__("dynamic", "no"),
         "$.bodies[1].dynamic: "),
        ("2d", VALID_S_2D, lambda s: s["bodies"][1].__setitem__("colour", [1, 2, 3]),
         "$.bodies[1]: "),
        ("2d", VALID_S_2D, lambda s: s["bodies"][0]["color_rgb"].__setitem__(1, 300),
         "$.bodies[0].color_rgb[1]: "),
        ("2d", VALID_S_2D, lambda s: s.__setitem__("dim", "3d"), "$.dim: "),
        ("3d", VALID_S_3D, lambda s: s["bodies"][0]["pose"].__setitem__("quat", [0, 0, 1]),
         "$.bodies[0].pose.quat: "),
        ("3d", VALID_S_3D, lambda s: s["bodies"][0]["material"].pop("friction"),
         "$.bodies[0].material: "),
        ("3d", VALID_S_3D, lambda s: s["bodies"][2]["shape"].pop("width_m"),
         "$.bodies[2].shape: "),
        ("3d", VALID_S_3D, lambda s: s["world"].__setitem__("gravity_m_s2", [0, -9.8]),
         "$.world.gravity_m_s2: "),
    ])
    def test_invalid_lists_the_problem_with_its_path(self, dim, base, edit, where):
        problems = spec_problems(_mutated(base, edit), dim)
        assert problems, "an invalid S must have problems"
        assert all(isinstance(p, str) and "\n" not in p for p in problems)
        assert any(p.startswith(where) for p in problems), problems

    def test_missing_key_is_named(self):
        problems = spec_problems(_mutated(VALID_S_2D, lambda s: s.pop("world")), "2d")
        assert problems == ["$: 'world' is a required property"]

    def test_limit_and_order(self):
        def wreck(s: dict) -> None:
            for body in s["bodies"]:
                body["dynamic"] = "maybe"
                body["color_rgb"] = "red"
            s["world"]["gravity_m_s2"] = None

        broken = _mutated(VALID_S_2D, wreck)
        everything = spec_problems(broken, "2d", limit=100)
        assert len(everything) >= 9
        assert spec_problems(broken, "2d") == everything[:5]
        assert spec_problems(broken, "2d", limit=2) == everything[:2]
        assert everything[0].startswith("$.bodies[0]")
        assert everything[-1].startswith("$.world.gravity_m_s2")


# =============================================================================================
# prompts: versions.json and the builders
# =============================================================================================
def _recorded_versions() -> dict:
    return json.loads((PROMPTS_DIR / "versions.json").read_text())


def _v(name: str) -> str:
    return f"{name}@{_recorded_versions()[name]['version']}"


TEMPLATE_NAMES = sorted(p.stem for p in PROMPTS_DIR.glob("*.txt"))


class TestTemplateVersions:
    """Every template is versioned and its text matches the recorded hash."""

    def test_every_template_has_an_entry_and_vice_versa(self):
        assert TEMPLATE_NAMES, "no templates found"
        assert sorted(_recorded_versions()) == TEMPLATE_NAMES

    @pytest.mark.parametrize("name", TEMPLATE_NAMES)
    def test_hash_matches(self, name):
        entry = _recorded_versions()[name]
        digest = hashlib.sha256((PROMPTS_DIR / f"{name}.txt").read_bytes()).hexdigest()
        assert digest == entry["sha256"], (
            f"{name}.txt changed without a new version: bump its version in versions.json and "
            f"record sha256 {digest}")

    @pytest.mark.parametrize("name", TEMPLATE_NAMES)
    def test_entry_shape(self, name):
        entry = _recorded_versions()[name]
        assert set(entry) == {"version", "sha256"}
        assert isinstance(entry["version"], int) and not isinstance(entry["version"], bool)
        assert entry["version"] >= 1
        assert re.fullmatch(r"[0-9a-f]{64}", entry["sha256"])

    def test_builder_reads_the_same_table(self):
        assert prompts.template_versions() == _recorded_versions()


def _png(path: Path, color: tuple[int, int, int]) -> np.ndarray:
    from PIL import Image

    frame = np.zeros((8, 8, 3), dtype=np.uint8)
    frame[...] = color
    frame[0, 0] = (1, 2, 3)
    Image.fromarray(frame).save(path)
    return frame


@pytest.fixture
def scene_factory(tmp_path):
    """Scenes whose key frames 1 and 10 are small PNGs on disk (no video is decoded)."""

    def make(dim: str = "2d", detection: bool = True) -> Scene:
        frames = {1: tmp_path / "f01.png", 10: tmp_path / "f10.png"}
        _png(frames[1], (255, 0, 0))
        _png(frames[10], (0, 0, 255))
        det = None
        if detection:
            det = tmp_path / "detection.json"
            det.write_text(json.dumps({"objects": [{"id": "red_ball", "bbox": [1, 2, 3, 4]}]}))
        sid = "task00001_000" if dim == "2d" else "01_tmpl_01"
        return Scene(scene_id=sid, dim=dim, clip=ClipInfo(fps=10.0, n_frames=20, width=8,
                                                          height=8),
                     video_path=tmp_path / "unused.mp4", detection_path=det,
                     keyframe_paths=frames)

    return make


UNFILLED = re.compile(r"\$(?:\{?[A-Za-z_])")  # a $placeholder left in a prompt


class TestBuildPrompt:
    """The prompt's version names exactly the templates it was built from."""

    def test_default_with_detection(self, scene_factory):
        text, images, version = prompts.build_prompt(
            scene_factory("2d"), "Use matter.js.", "javascript", prompts.PromptSettings())
        assert version == "+".join([_v("default"), _v("spec_2d"), _v("detection")])
        assert version == "default@2+spec_2d@1+detection@1"  # the documented example
        assert [img.name for img in images] == ["frame_01", "frame_10"]
        assert "Use matter.js." in text and "```javascript" in text
        assert "red_ball" in text
        assert (PROMPTS_DIR / "spec_2d.txt").read_text().rstrip("\n") in text
        assert not UNFILLED.search(text)

    def test_images_are_the_key_frames_as_png(self, scene_factory):
        from PIL import Image

        scene = scene_factory("2d")
        _, images, _ = prompts.build_prompt(scene, "", "python", prompts.PromptSettings())
        for img, index in zip(images, (1, 10)):
            assert img.png.startswith(b"\x89PNG\r\n\x1a\n")
            decoded = np.asarray(Image.open(io.BytesIO(img.png)).convert("RGB"))
            assert np.array_equal(decoded, scene.key_frame(index))

    def test_without_detection(self, scene_factory):
        settings = prompts.PromptSettings(detection=False)
        text, _, version = prompts.build_prompt(scene_factory("2d"), "", "python", settings)
        assert version == f"{_v('default')}+{_v('spec_2d')}"
        assert "red_ball" not in text

    def test_detection_wanted_but_scene_has_none(self, scene_factory):
        _, _, version = prompts.build_prompt(scene_factory("2d", detection=False), "", "python",
                                             prompts.PromptSettings(detection=True))
        assert version == f"{_v('default')}+{_v('spec_2d')}"

    def test_timed_3d(self, scene_factory):
        settings = prompts.PromptSettings(timed=True)
        text, _, version = prompts.build_prompt(scene_factory("3d"), "", "javascript", settings)
        assert version == "+".join([_v("default"), _v("spec_3d"), _v("timing"),
                                    _v("detection")])
        # fps 10, 20 frames: a 2 s clip; frames 1 and 10 are 0.9 s apart
        assert "10 frames per second" in text and "20 frames (2 s)" in text
        assert "0.9 s apart" in text
        assert (PROMPTS_DIR / "spec_3d.txt").read_text().rstrip("\n") in text
        assert not UNFILLED.search(text)

    def test_forecast_only(self, scene_factory):
        settings = prompts.PromptSettings(forecast_only=True, timed=True, detection=False)
        text, images, version = prompts.build_prompt(scene_factory("2d"), "", "python",
                                                     settings)
        assert [img.name for img in images] == ["frame_01"]
        assert "first frame (frame 1)" in text and "0 s apart" in text
        assert version == f"{_v('default')}+{_v('spec_2d')}+{_v('timing')}"


class TestOtherPrompts:
    """Repair, judge and reference-caption prompts and their versions."""

    def test_repair_version(self):
        assert prompts.repair_version("default@2+spec_2d@1") == \
            f"default@2+spec_2d@1+{_v('repair')}"

    def test_repair_prompt(self):
        text = prompts.build_repair_prompt("ORIGINAL PROMPT", "python",
                                           "print('$HOME costs $5')", "runtime_error",
                                           "  Traceback: boom \n")
        assert text.startswith("ORIGINAL PROMPT")
        assert "print('$HOME costs $5')" in text  # program text is not a template
        assert "(runtime_error)" in text and "Traceback: boom" in text
        assert "```python" in text

    def test_repair_prompt_truncates_and_fills_empty_errors(self):
        text = prompts.build_repair_prompt("", "js", "x" * 50, "no_code", "   ",
                                           max_program_chars=10)
        assert "x" * 10 + "\n/* … truncated … */" in text and "x" * 11 not in text
        assert "(no error text)" in text

    def test_judge_prompt_video(self):
        text, version = prompts.judge_prompt("video")
        assert text == (PROMPTS_DIR / "judge_video.txt").read_text()
        assert version == _v("judge_video")

    def test_judge_prompt_frames(self):
        text, version = prompts.judge_prompt("frames", n_frames=8, duration_s=2.5)
        assert version == _v("judge_frames")
        assert "(8 frames each" in text and "2.5 s" in text
        assert not UNFILLED.search(text)

    def test_reference_caption_prompt(self):
        text, version = prompts.reference_caption_prompt(6, 4.0)
        assert version == _v("reference_caption")
        assert text.startswith("These are 6 frames") and "(4 s)" in text
        assert not UNFILLED.search(text)

    def test_version_of_joins_in_order(self):
        assert prompts.version_of(["timing", "default"]) == f"{_v('timing')}+{_v('default')}"
