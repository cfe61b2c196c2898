"""LLM judges served by a provider API: ``gemini``, ``gpt_frames``, ``qwen_vl``, ``claude_frames``.

One class (`ApiJudge`) serves all four; ``conf/judge/<name>.yaml`` says which provider and model,
and whether the judge watches the two clips (``input: video``; Gemini and Qwen-VL accept MP4) or
``frames`` uniformly sampled frames of each clip (``frames: k`` per clip; for APIs that take only
images). The message is the judge prompt (`visphy_core.calls.prompts.build.judge_prompt`), then the
ground truth, then the clip under judgement: [text, reference.mp4, generated.mp4] or [text,
k reference PNGs, k generated PNGs], each clip's frames in time order.

A reply goes through `visphy_core.api.judge.parse_verdict`; a provider failure after retries, a
refusal, a reply cut by the token limit, no JSON or a score outside 1–10 give an **invalid**
verdict with its reason (counted, never a number).
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Optional

from visphy_core.api.calls import judge_prompt
from visphy_core.api.config_schema import JudgeConfig
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.judge import Judge, JudgeInput, Verdict, parse_verdict, uniform_indices
from visphy_core.api.media import decode_video, png_bytes
from visphy_plugins.providers.preflight import LocalKeyCaller, is_local, preflight
from visphy_plugins.providers.base import ApiCaller, Part
from visphy_plugins.providers.config import ApiSettings

API_JUDGES = ("gemini", "gpt_frames", "qwen_vl", "claude_frames")


class JudgeInputKind(StrEnum):
    video = "video"     # both clips as MP4 (the provider must accept video)
    frames = "frames"   # `frames` uniformly sampled PNG frames of each clip


@dataclass
class ApiJudgeConfig(JudgeConfig, ApiSettings):
    """An API judge (``schema_api_judge``): the provider settings plus what the judge sees."""

    input: JudgeInputKind = JudgeInputKind.video
    frames: int = field(default=8, metadata={"min": 1, "max": 64})  # per clip, input=frames
    max_output_tokens: int = field(default=2048, metadata={"min": 1})
    temperature: Optional[float] = field(default=0.0, metadata={"min": 0, "max": 2})


def _one_line(text: str, limit: int = 500) -> str:
    return " ".join(str(text).split())[:limit]


class ApiJudge(Judge):
    """A judge that asks a multimodal model through `ApiCaller` (retries, limiter, cost)."""

    version = "1"

    def __init__(self, cfg: Any):
        super().__init__(cfg)
        self.name = str(cfg.name)
        # an OpenAI-compatible server on this machine or network (vLLM, Ollama, llama.cpp)
        local = str(cfg.get("provider") or "openai") == "openai" and is_local(cfg.get("base_url"))
        self.api = (LocalKeyCaller if local else ApiCaller)(cfg, f"judge={self.name}")
        self.needs_key = None if local else self.api.key_env
        self.input_kind = str(cfg.get("input") or "video")
        self.frames = int(cfg.get("frames") or 8)

    @property
    def prompt_version(self) -> str:
        return judge_prompt(self.input_kind)[1]

    @property
    def sampling(self) -> str:
        return ("video" if self.input_kind == "video"
                else f"uniform:{self.frames} frames per clip")

    def check_ready(self) -> None:
        """The models' pre-flight: the key, the model id, and an OpenAI-compatible server's
        model list (`visphy_plugins.providers.preflight`)."""
        preflight(self.cfg, f"judge={self.name}", self.api)

    def identity(self) -> str:
        """Name, class version, generation settings, input kind, frames (frame judges only) and
        prompt version; never the base URL, timeouts, retries or prices."""
        return json.dumps(["api_judge", self.name, self.version, self.api.identity(),
                           self.input_kind,
                           self.frames if self.input_kind == "frames" else None,
                           self.prompt_version], sort_keys=True, default=str)

    def describe(self) -> dict:
        return {"name": self.name, "provider": str(self.cfg.provider),
                "model_id": str(self.cfg.model_id), "input": self.input_kind,
                "sampling": self.sampling, "prompt_version": self.prompt_version}

    # ------------------------------------------------------------------ the message
    def build_parts(self, inp: JudgeInput) -> tuple[list[Part], str, str]:
        """The message parts (reference before generated), prompt version and sampling."""
        if self.input_kind == "video":
            text, version = judge_prompt("video")
            return [Part("text", text=text),
                    Part("video", data=inp.reference_video.read_bytes()),
                    Part("video", data=inp.generated_video.read_bytes())], version, "video"
        images: list[Part] = []
        counts = []
        for path in (inp.reference_video, inp.generated_video):
            frames, _ = decode_video(path)
            idx = uniform_indices(len(frames), self.frames)
            counts.append(len(idx))
            images += [Part("image", data=png_bytes(frames[i])) for i in idx]
        k = min(counts)  # fewer than `frames` only for a clip shorter than that
        duration = inp.n_frames / inp.fps if inp.fps else 0.0
        text, version = judge_prompt("frames", n_frames=k, duration_s=duration)
        return [Part("text", text=text), *images], version, f"uniform:{k} frames per clip"

    # ------------------------------------------------------------------ one verdict
    async def ajudge(self, inp: JudgeInput) -> Verdict:
        configured = str(self.cfg.model_id)
        verdict = Verdict(judge=self.name, judge_model=configured,
                          prompt_version=self.prompt_version, sampling=self.sampling)
        try:  # decoding and PNG encoding off the event loop: other judges' calls go on
            parts, verdict.prompt_version, verdict.sampling = await asyncio.to_thread(
                self.build_parts, inp)
        except (OSError, ValueError) as exc:  # an unreadable clip: no call is made
            verdict.error = _one_line(f"cannot read the clips: {type(exc).__name__}: {exc}")
            return verdict
        result = await self.api.complete(parts)
        verdict.latency_s = result.latency_s
        verdict.transport_attempts = result.attempts
        if result.error is not None:
            verdict.error = _one_line(result.error.describe())
            verdict.error_kind = result.error.kind.value
            return verdict
        c = result.completion
        assert c is not None
        verdict.judge_model = c.model_id or configured
        verdict.raw = c.text
        verdict.usage = dict(c.usage)
        verdict.cost_usd = result.cost_usd
        if c.refusal or c.finish_reason in ("refusal", "content_filter"):
            verdict.error = _one_line(f"refused: {c.refusal or c.finish_reason}")
            return verdict
        if c.finish_reason == "length":
            verdict.error = (f"truncated: the reply hit max_output_tokens="
                             f"{int(self.cfg.max_output_tokens)}")
            return verdict
        score, justification, error = parse_verdict(c.text)
        verdict.justification = justification
        if error is not None:
            verdict.error = _one_line(error)
            return verdict
        verdict.score, verdict.valid = score, True
        return verdict

    async def aclose(self) -> None:
        await self.api.aclose()


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="judge", name="schema_api_judge", node=ApiJudgeConfig)


@hookimpl
def visphy_register_judges(register):
    for name in API_JUDGES:
        register(name, ApiJudge)
