"""Judge ``example_pixels``: a 1–10 verdict from how far the clip is from the ground truth.

A real judge asks a multimodal model (`visphy_plugins.judges.api_judges`); this one needs no
key: it decodes both clips and maps their mean absolute difference to a score. A verdict is
never raised: what went wrong is an *invalid* verdict with its reason (counted, never a score).
``judge=example_pixels`` selects it (config entry in ``configs.py``).
"""

from __future__ import annotations

import asyncio

import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.judge import Judge, JudgeInput, Verdict
from visphy_core.api.media import decode_video


class PixelJudge(Judge):
    name = "example_pixels"
    version = "1"          # part of every cached verdict's identity, with the config
    input_kind = "video"

    def _score(self, inp: JudgeInput) -> float:
        reference, _ = decode_video(inp.reference_video)
        generated, _ = decode_video(inp.generated_video)
        n = min(len(reference), len(generated))
        diff = np.abs(reference[:n].astype(float) - generated[:n].astype(float))
        per_frame = diff.mean(axis=(1, 2, 3))
        cfg = self.cfg or {}
        mae = per_frame.max() if cfg.get("reduce") == "max" else per_frame.mean()
        return round(10.0 - 9.0 * min(1.0, mae / float(cfg.get("scale", 32.0))), 2)

    async def ajudge(self, inp: JudgeInput) -> Verdict:
        verdict = Verdict(judge=self.name, judge_model="mean absolute difference",
                          prompt_version="none", sampling="video")
        try:  # decoding is blocking work: off the event loop, other judges go on meanwhile
            score = await asyncio.to_thread(self._score, inp)
        except (OSError, ValueError) as exc:
            verdict.error = f"cannot read the clips: {exc}"
            return verdict
        verdict.score, verdict.valid = score, True
        verdict.justification = f"{score:g}/10 from the pixel difference"
        return verdict


@hookimpl
def visphy_register_judges(register):
    register(PixelJudge.name, PixelJudge)  # factory(cfg) -> Judge
