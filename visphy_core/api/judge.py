"""The judge contract: a model that compares a generated clip with the ground truth, 1–10.

A `Judge` plugin receives both videos (`JudgeInput`) and returns a `Verdict`. Parsing is shared
(`parse_verdict`): a reply may wrap its JSON in a fence or in prose; a score outside 1–10, a
missing score or no JSON at all make the verdict **invalid** (counted, never a number). The
verdict records the judge's model, prompt version and frame-sampling policy; `JudgeCaller`
caches verdicts by (judge identity, both clips) and books every call in the run's ledger.
"""

from __future__ import annotations

import json
import re
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

SCORE_RANGE = (1.0, 10.0)


@dataclass(frozen=True)
class JudgeInput:
    scene_id: str
    dim: str
    reference_video: Path     # the ground-truth clip
    generated_video: Path     # the clip under judgement, already on the reference's contract
    fps: float
    n_frames: int


@dataclass
class Verdict:
    judge: str
    score: float | None = None
    justification: str = ""
    valid: bool = False
    error: str | None = None        # why the verdict is invalid (parse, range, call failure)
    error_kind: str | None = None   # for call failures: calls.CallErrorKind
    raw: str = ""                   # the judge's reply text
    judge_model: str = ""
    prompt_version: str = ""
    sampling: str = ""              # "video" or "uniform:<n> frames per clip"
    usage: dict[str, int] = field(default_factory=dict)
    cost_usd: float | None = None
    latency_s: float = 0.0
    transport_attempts: int = 0

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


_FENCED = re.compile(r"```(?:json|JSON)?\s*\n(.*?)```", re.S)


def _json_objects(text: str) -> list[Any]:
    """Every top-level JSON object in ``text``: fenced blocks first, then balanced braces."""
    found: list[Any] = []
    for body in _FENCED.findall(text):
        try:
            found.append(json.loads(body))
        except ValueError:
            pass
    decoder = json.JSONDecoder()
    pos = 0
    while True:
        start = text.find("{", pos)
        if start == -1:
            break
        try:
            value, end = decoder.raw_decode(text, start)
        except ValueError:
            pos = start + 1
            continue
        found.append(value)
        pos = end
    return found


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(-?\d+(?:\.\d+)?)\s*(?:/\s*10)?\s*", value)
        if m:
            return float(m.group(1))
    return None


def parse_verdict(text: str, score_range: tuple[float, float] = SCORE_RANGE
                  ) -> tuple[float | None, str, str | None]:
    """(score, justification, error) from a judge's reply.

    Accepts ``{"score": 7, "justification": "..."}`` bare, fenced, or inside prose; ``"7/10"``
    or ``"7"`` as a string score. ``error`` is set (and score None) when there is no JSON object
    with a numeric ``score``, or when the score is outside ``score_range``.
    """
    if not text or not text.strip():
        return None, "", "empty reply"
    candidates = [o for o in _json_objects(text) if isinstance(o, dict) and "score" in o]
    if not candidates:
        return None, "", "no JSON object with a score in the reply"
    obj = candidates[0]
    score = _number(obj.get("score"))
    justification = str(obj.get("justification") or obj.get("reason") or "").strip()
    if score is None:
        return None, justification, f"score {obj.get('score')!r} is not a number"
    lo, hi = score_range
    if not lo <= score <= hi or not np.isfinite(score):
        return None, justification, f"score {score:g} outside {lo:g}–{hi:g}"
    return score, justification, None


def uniform_indices(n_frames: int, k: int) -> list[int]:
    """``k`` frame indices spread evenly over a clip, first and last included."""
    if n_frames <= 0:
        return []
    k = max(1, min(k, n_frames))
    if k == 1:
        return [0]
    return sorted({int(round(i * (n_frames - 1) / (k - 1))) for i in range(k)})


class Judge(ABC):
    """Base class for judge plugins."""

    name: str = ""
    version: str = "1"
    needs_key: str | None = None
    #: "video" (the judge watches both clips) or "frames" (uniformly sampled frames).
    input_kind: str = "video"

    def __init__(self, cfg: Any = None):
        self.cfg = cfg

    def check_ready(self) -> None:
        """Raise a `UserError` when the judge cannot run (missing key); before any work."""

    def unavailable_reason(self) -> str | None:
        """Why this judge cannot run here (weights missing, ...): verdicts are then reported
        as unavailable, never as numbers."""
        return None

    @abstractmethod
    async def ajudge(self, inp: JudgeInput) -> Verdict:
        """One verdict; never raises for a provider failure (an invalid verdict instead)."""

    def identity(self) -> str:
        """Cache identity: everything that changes a verdict (model, prompt, sampling)."""
        from visphy_core.api.model import config_identity

        return config_identity(self.name, self.version, self.cfg)

    async def aclose(self) -> None:
        """Release clients."""
