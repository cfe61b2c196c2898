"""Tokens, money and the run's cost cap.

Every call that reaches a provider is one line of the run's ledger ``calls.jsonl`` (fsynced:
money spent is never forgotten, even by a killed run), with its stage (``generate``, ``repair``,
``judge``, ``reference``), tokens and cost. Cache hits are counted too, apart, so the summary can
say both what this run paid and what its replies cost when they were first bought.

Cost is computed from the usage the provider reports and a price table in the model's config
(``price: {input_usd_per_mtok, output_usd_per_mtok, cached_input_usd_per_mtok}``); a model
without a price has cost ``None`` and a cost cap refuses to run it.

The cap (``run.cost_cap_usd``) is checked before each new call: once spent money plus the
expected cost of the calls in flight reaches it, no new call starts (`CostCapReached`); calls
already sent finish and are recorded. A call in flight is expected to cost the mean of the calls
paid so far; before the first is paid, `first_call_usd` (`call_cost_bound`: the model's price
for a prompt of `PROMPT_TOKENS_BOUND` tokens and a reply as long as its ``max_output_tokens``),
so the first calls of a run cannot all start at once and overshoot a small cap. A resumed run
reads its ledger back, so the cap covers the whole run, not one process.
"""

from __future__ import annotations

import json
import os
import threading
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping

STAGES = ("generate", "repair", "judge", "reference")
TOKEN_FIELDS = ("input_tokens", "output_tokens", "cached_input_tokens", "reasoning_tokens")


class CostCapReached(Exception):
    """A new call would exceed ``run.cost_cap_usd``: the run stops cleanly."""

    def __init__(self, cap_usd: float, spent_usd: float):
        super().__init__(f"cost cap ${cap_usd:.2f} reached (${spent_usd:.4f} spent); no new "
                         "calls were made")
        self.cap_usd = cap_usd
        self.spent_usd = spent_usd


@dataclass(frozen=True)
class Price:
    input_usd_per_mtok: float
    output_usd_per_mtok: float
    cached_input_usd_per_mtok: float | None = None

    @classmethod
    def from_cfg(cls, price: Mapping[str, Any] | None) -> "Price | None":
        if not price or price.get("input_usd_per_mtok") is None \
                or price.get("output_usd_per_mtok") is None:
            return None
        cached = price.get("cached_input_usd_per_mtok")
        return cls(float(price["input_usd_per_mtok"]), float(price["output_usd_per_mtok"]),
                   None if cached is None else float(cached))

    def cost(self, usage: Mapping[str, int]) -> float:
        """USD for one call: uncached input, cached input (at its own price when given) and
        output (reasoning tokens are billed as output and already counted in it)."""
        inp = int(usage.get("input_tokens", 0))
        cached = min(int(usage.get("cached_input_tokens", 0)), inp)
        cached_price = (self.input_usd_per_mtok if self.cached_input_usd_per_mtok is None
                        else self.cached_input_usd_per_mtok)
        return ((inp - cached) * self.input_usd_per_mtok + cached * cached_price
                + int(usage.get("output_tokens", 0)) * self.output_usd_per_mtok) / 1e6


@dataclass
class CallRecord:
    """One line of ``calls.jsonl``."""

    stage: str
    scene_id: str
    caller: str                  # model or judge name
    provider: str | None
    model_id: str | None
    cached: bool                 # answered from the cache (no call made, nothing paid now)
    ok: bool
    cost_usd: float | None = None
    latency_s: float = 0.0
    transport_attempts: int = 0
    error_kind: str | None = None
    usage: dict[str, int] = field(default_factory=dict)


def _empty_totals() -> dict[str, Any]:
    return {"calls": 0, "cache_hits": 0, "errors": 0, "cost_usd": 0.0,
            "cost_usd_incl_cached": 0.0, "unpriced_calls": 0,
            **{f: 0 for f in TOKEN_FIELDS}}


#: input tokens assumed for one call before any is paid: the prompt text, the object list and
#: two key frames come to about 2,500 (4,500 where a provider counts image tokens higher)
PROMPT_TOKENS_BOUND = 5000


def call_cost_bound(model_cfg: Mapping[str, Any] | None) -> float:
    """USD one call of this model may cost at most, by its config: `PROMPT_TOKENS_BOUND` input
    tokens and a reply of ``max_output_tokens`` (0 when the model has no token price)."""
    if not model_cfg:
        return 0.0
    price = Price.from_cfg(model_cfg.get("price"))
    if price is None:
        return 0.0
    out = int(model_cfg.get("max_output_tokens") or 0)
    return price.cost({"input_tokens": PROMPT_TOKENS_BOUND, "output_tokens": out})


class UsageLedger:
    """Thread-safe ledger of calls, written through to ``path`` when given. ``first_call_usd``:
    what a call in flight is expected to cost before any call has been paid."""

    def __init__(self, path: Path | None = None, cap_usd: float | None = None,
                 first_call_usd: float = 0.0):
        self.path = path
        self.cap_usd = cap_usd
        self.first_call_usd = float(first_call_usd)
        self._lock = threading.Lock()
        self._records: list[CallRecord] = []
        self._in_flight: set[int] = set()  # tickets of calls sent and not yet recorded
        self._next = 0
        self.stopped_by_cap = False
        if path is not None and path.is_file():
            text = path.read_text()
            for line in text.splitlines():
                try:
                    self._records.append(CallRecord(**json.loads(line)))
                except (ValueError, TypeError):
                    continue  # a half-written last line of a killed run
            if text and not text.endswith("\n"):
                with open(path, "a") as fh:  # end the fragment so the next record stands alone
                    fh.write("\n")

    # ------------------------------------------------------------------ the cap
    @property
    def spent_usd(self) -> float:
        return sum(r.cost_usd or 0.0 for r in self._records if not r.cached)

    def _expected_call_cost(self) -> float:
        paid = [r.cost_usd for r in self._records if not r.cached and r.cost_usd]
        return sum(paid) / len(paid) if paid else self.first_call_usd

    def reserve(self) -> int:
        """Before a new call: a ticket, or `CostCapReached` when the cap forbids the call."""
        with self._lock:
            if self.cap_usd is not None:
                # each call in flight at today's expectation: the first paid call re-prices
                # the ones sent before it
                committed = self.spent_usd + len(self._in_flight) * self._expected_call_cost()
                if committed >= self.cap_usd:
                    self.stopped_by_cap = True
                    raise CostCapReached(self.cap_usd, self.spent_usd)
            self._next += 1
            self._in_flight.add(self._next)
            return self._next

    def release(self, ticket: int) -> None:
        with self._lock:
            self._in_flight.discard(ticket)

    # ------------------------------------------------------------------ recording
    def record(self, rec: CallRecord, ticket: int | None = None) -> None:
        with self._lock:
            if ticket is not None:
                self._in_flight.discard(ticket)
            self._records.append(rec)
            if self.path is not None:
                with open(self.path, "a") as fh:
                    fh.write(json.dumps(asdict(rec), sort_keys=True) + "\n")
                    fh.flush()
                    os.fsync(fh.fileno())

    def totals(self) -> dict[str, dict[str, Any]]:
        """Per stage (and ``all``): calls made, cache hits, errors, tokens and cost."""
        out: dict[str, dict[str, Any]] = defaultdict(_empty_totals)
        with self._lock:
            records = list(self._records)
        for rec in records:
            for key in (rec.stage, "all"):
                t = out[key]
                if rec.cached:
                    t["cache_hits"] += 1
                    t["cost_usd_incl_cached"] += rec.cost_usd or 0.0
                    continue
                t["calls"] += 1
                t["errors"] += 0 if rec.ok else 1
                if rec.cost_usd is None and rec.ok:
                    t["unpriced_calls"] += 1
                t["cost_usd"] += rec.cost_usd or 0.0
                t["cost_usd_incl_cached"] += rec.cost_usd or 0.0
                for f in TOKEN_FIELDS:
                    t[f] += int(rec.usage.get(f, 0) or 0)
        order = [s for s in STAGES if s in out] + sorted(k for k in out if k not in STAGES)
        return {k: dict(out[k]) for k in order}
