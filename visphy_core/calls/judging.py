"""Run the selected judges on one scene: cached verdicts, ledger entries, the cost cap.

Verdicts are cached by (judge identity, reference clip, generated clip): re-judging the same
videos never calls a judge twice. Invalid verdicts (unparsable, out of range, a failed call) are
kept and counted, never turned into numbers; failed calls are not cached.
"""

from __future__ import annotations

import json
from pathlib import Path

from visphy_core.api.judge import Judge, JudgeInput, Verdict
from visphy_core.calls.generation import GenerationService, get_service
from visphy_core.calls.usage import CallRecord, UsageLedger
from visphy_core.infra.cache import Cache, content_key, read_json
from visphy_core.infra.secrets import redact


def _verdict_from_entry(entry: Path) -> Verdict:
    return Verdict(**read_json(entry / "verdict.json"))


class JudgeCaller:
    """The selected judges, as ``(selection key, Judge)`` pairs, behind one cache and ledger."""

    def __init__(self, judges: list[tuple[str, Judge]], cache: Cache, ledger: UsageLedger,
                 service: GenerationService | None = None):
        self.judges = judges
        self.cache = cache
        self.ledger = ledger
        self.service = service or get_service()
        self._identities = {key: judge.identity() for key, judge in judges}

    def column(self, key: str) -> str:
        return f"judge_{key}"

    def judge_scene(self, inp: JudgeInput, clips_key: str) -> dict[str, Verdict]:
        """Every judge's verdict on one pair of clips (blocking; judges run concurrently)."""

        async def all_verdicts() -> list[Verdict]:
            import asyncio

            return list(await asyncio.gather(*(self._one(key, judge, inp, clips_key)
                                               for key, judge in self.judges)))

        verdicts = self.service.run(all_verdicts())
        return {key: v for (key, _), v in zip(self.judges, verdicts)}

    async def _one(self, key: str, judge: Judge, inp: JudgeInput, clips_key: str) -> Verdict:
        reason = judge.unavailable_reason()
        if reason:
            return Verdict(judge=key, error=f"unavailable: {reason}")
        cache_key = content_key("verdict", self._identities[key], clips_key)
        hit = self.cache.load("verdict", cache_key, _verdict_from_entry)
        provider = getattr(getattr(judge, "cfg", None), "get", lambda *_: None)("provider")
        if hit is not None:
            self.ledger.record(CallRecord(stage="judge", scene_id=inp.scene_id, caller=key,
                                          provider=provider, model_id=hit.judge_model,
                                          cached=True, ok=True, cost_usd=hit.cost_usd,
                                          usage=dict(hit.usage)))
            return hit
        ticket = self.ledger.reserve()
        try:
            verdict = await judge.ajudge(inp)
        except BaseException:
            self.ledger.release(ticket)
            raise
        verdict.judge = key
        verdict.error = redact(verdict.error)
        self.ledger.record(CallRecord(
            stage="judge", scene_id=inp.scene_id, caller=key, provider=provider,
            model_id=verdict.judge_model, cached=False, ok=verdict.error_kind is None,
            cost_usd=verdict.cost_usd, latency_s=verdict.latency_s,
            transport_attempts=verdict.transport_attempts, error_kind=verdict.error_kind,
            usage=dict(verdict.usage)), ticket)
        if verdict.error_kind is None:  # a failed call may succeed next time
            self.cache.put("verdict", cache_key,
                           {"verdict.json": json.dumps(verdict.to_json(), default=str)})
        return verdict

    def close(self) -> None:
        async def close_all() -> None:
            for _, judge in self.judges:
                await judge.aclose()

        self.service.run(close_all())
