"""``videoscore2``: TIGER-Lab's VideoScore2 as a local, open-weights judge.

VideoScore2 (He et al. 2025, arXiv:2509.22799; weights ``TIGER-Lab/VideoScore2``, a fine-tune
of Qwen2.5-VL-7B-Instruct) watches **one** video and a text prompt, reasons, and ends its answer
with three integer scores on 1–5::

    visual quality: <v>; text-to-video alignment: <t>, physical/common-sense consistency: <p>

It is a *no-reference* evaluator: it never sees the ground truth, so it measures how plausible
the generated clip is (and how well it fits ``description``), not how faithfully it reproduces
the reference. Use it next to a comparing judge, not instead of one.

Score mapping (explicit, linear, 1→1 and 5→10): ``score = 1 + (s − 1) · 9/4`` where ``s`` is
``physical/common-sense consistency`` (``aggregate: physical``, the default: visphy measures
physical understanding) or the mean of the three dimensions (``aggregate: mean``). All three
dimensions and the model's reasoning are kept in the verdict's ``raw`` (JSON).

Weights are read only from disk: ``weights_dir``, else ``$VISPHY_WEIGHTS/videoscore2``; nothing is
downloaded. Without torch, transformers or the weights, `unavailable_reason` says which piece is
missing and the judge yields no score. Inference is greedy (``do_sample=False``), so a verdict is
reproducible; the authors' script samples at temperature 0.7.
"""

from __future__ import annotations

import asyncio
import hashlib
import importlib.util
import json
import os
import re
import threading
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from string import Template
from typing import Any, Optional

import numpy as np

from visphy_core.api.calls import CallErrorKind
from visphy_core.api.config_schema import JudgeConfig
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.judge import Judge, JudgeInput, Verdict
from visphy_core.api.media import decode_video
from visphy_core.api.settings import cfg_get

DIMENSIONS = ("visual_quality", "text_alignment", "physical_consistency")
PROMPT_VERSION = "videoscore2_query@1"

#: The query format VideoScore2 was trained on (from the authors' inference script): it names the
#: three dimensions and the exact answer lines the scores are parsed from.
QUERY = Template("""
You are an expert for evaluating AI-generated videos from three dimensions:
(1) visual quality – clarity, smoothness, artifacts;
(2) text-to-video alignment – fidelity to the prompt;
(3) physical/common-sense consistency – naturalness and physics plausibility.

Video prompt: $description

Please output in this format:
visual quality: <v_score>;
text-to-video alignment: <t_score>,
physical/common-sense consistency: <p_score>
""")

_SCORES = re.compile(r"visual quality:\s*(\d+).*?text-to-video alignment:\s*(\d+).*?"
                     r"physical/common-sense consistency:\s*(\d+)", re.S | re.I)

DOWNLOAD_HINT = ("download the weights once where there is internet (huggingface-cli download "
                 "TIGER-Lab/VideoScore2 --local-dir <dir>) and set judge.videoscore2.weights_dir="
                 "<dir> or put them at $VISPHY_WEIGHTS/videoscore2")


class Aggregate(StrEnum):
    physical = "physical"   # physical/common-sense consistency only
    mean = "mean"           # mean of the three dimensions


class DType(StrEnum):
    auto = "auto"
    bfloat16 = "bfloat16"
    float16 = "float16"
    float32 = "float32"


@dataclass
class VideoScore2JudgeConfig(JudgeConfig):
    """``schema_videoscore2_judge``."""

    weights_dir: Optional[str] = None   # null: $VISPHY_WEIGHTS/videoscore2
    aggregate: Aggregate = Aggregate.physical
    # The "video prompt" the text-to-video alignment dimension refers to.
    description: str = ("A physics simulation: simple rigid objects move under gravity, fall, "
                        "collide, bounce and come to rest.")
    infer_fps: float = field(default=2.0, metadata={"min": 0.1, "max": 60})  # frames seen per s
    max_new_tokens: int = field(default=1024, metadata={"min": 16, "max": 8192})
    device: str = "auto"                # auto: cuda when available, else cpu
    dtype: DType = DType.bfloat16


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in re.findall(r"\d+", text)[:2])


def to_ten(s: float) -> float:
    """A 1–5 VideoScore2 score on visphy's 1–10 scale: linear, 1→1, 3→5.5, 5→10."""
    return 1.0 + (float(s) - 1.0) * 9.0 / 4.0


def parse_scores(text: str) -> dict[str, int] | None:
    """The three 1–5 scores at the end of a VideoScore2 answer, or None."""
    m = _SCORES.search(text or "")
    return dict(zip(DIMENSIONS, (int(g) for g in m.groups()))) if m else None


def sample_indices(n_frames: int, fps: float, infer_fps: float) -> list[int]:
    """Frames at ``infer_fps`` over the clip: an even count (Qwen2.5-VL pairs frames in time),
    at least 4 (repeating frames of a very short clip, as `qwen_vl_utils` does)."""
    duration = n_frames / fps if fps else 0.0
    count = max(4, int(round(duration * infer_fps)))
    count -= count % 2
    return [int(round(x)) for x in np.linspace(0, n_frames - 1, count)]


class VideoScore2Judge(Judge):
    name = "videoscore2"
    version = "1"
    needs_key = None
    input_kind = "video"

    def __init__(self, cfg: Any):
        super().__init__(cfg)
        self._model: Any = None
        self._processor: Any = None
        self._device = "cpu"
        self._lock = threading.Lock()

    def _get(self, key: str, default: Any) -> Any:
        return cfg_get(self.cfg, key, default)

    def weights_path(self) -> Path | None:
        configured = self._get("weights_dir", None)
        if configured:
            return Path(str(configured)).expanduser()
        root = os.environ.get("VISPHY_WEIGHTS")
        return Path(root).expanduser() / "videoscore2" if root else None

    def unavailable_reason(self) -> str | None:
        missing = [f"{mod} is not installed ({hint})" for mod, hint in (
            ("torch", "pip install -e '.[metrics]'"),
            ("transformers", "pip install 'transformers>=4.49' accelerate"))
            if importlib.util.find_spec(mod) is None]
        path = self.weights_path()
        if path is None:
            missing.append("no weights directory: judge.videoscore2.weights_dir is null and "
                           "$VISPHY_WEIGHTS is not set")
        elif not path.is_dir():
            missing.append(f"weights directory {path} does not exist")
        elif not (path / "config.json").is_file():
            missing.append(f"weights directory {path} has no config.json (not a transformers "
                           "model directory)")
        if not missing:
            return None
        hint = DOWNLOAD_HINT if any("weights" in m for m in missing) else ""
        return "videoscore2: " + "; ".join(missing) + (f"; {hint}" if hint else "")

    def _weights_fingerprint(self) -> str | None:
        path = self.weights_path()
        if path is None or not (path / "config.json").is_file():
            return None
        h = hashlib.sha256((path / "config.json").read_bytes())
        for f in sorted(path.glob("*.safetensors")):
            h.update(f"{f.name}:{f.stat().st_size}".encode())
        return h.hexdigest()[:16]

    def identity(self) -> str:
        """Weights (config.json and shard sizes, not their path), prompt, sampling and mapping."""
        return json.dumps([self.name, self.version, PROMPT_VERSION, self._weights_fingerprint(),
                           str(self._get("aggregate", "physical")),
                           str(self._get("description", "")),
                           float(self._get("infer_fps", 2.0)),
                           int(self._get("max_new_tokens", 1024)),
                           str(self._get("dtype", "bfloat16"))], sort_keys=True)

    # ------------------------------------------------------------------ model
    def _load(self) -> None:
        import torch
        import transformers
        from transformers import AutoProcessor

        auto_model = (getattr(transformers, "AutoModelForImageTextToText", None)
                      or transformers.AutoModelForVision2Seq)
        device = str(self._get("device", "auto"))
        if device == "auto":
            device = "cuda" if torch.cuda.is_available() else "cpu"
        dtype = str(self._get("dtype", "bfloat16"))
        dtype_arg = {"dtype" if _version(transformers.__version__) >= (4, 56) else "torch_dtype":
                     "auto" if dtype == "auto" else getattr(torch, dtype)}
        path = str(self.weights_path())
        self._model = auto_model.from_pretrained(path, **dtype_arg).to(device).eval()
        self._processor = AutoProcessor.from_pretrained(path)
        self._device = device

    def _infer(self, video: Path) -> str:
        """VideoScore2's answer for one clip (blocking; one clip at a time per process)."""
        import torch

        with self._lock:
            if self._model is None:
                self._load()
            frames, info = decode_video(video)
            infer_fps = float(self._get("infer_fps", 2.0))
            clip = frames[sample_indices(len(frames), info.fps, infer_fps)]
            query = QUERY.substitute(description=str(self._get("description", "")))
            messages = [{"role": "user", "content": [{"type": "video"},
                                                     {"type": "text", "text": query}]}]
            text = self._processor.apply_chat_template(messages, tokenize=False,
                                                       add_generation_prompt=True)
            inputs = self._processor(text=[text], videos=[clip], fps=infer_fps, padding=True,
                                     return_tensors="pt").to(self._device)
            with torch.inference_mode():
                out = self._model.generate(**inputs, do_sample=False,
                                           max_new_tokens=int(self._get("max_new_tokens", 1024)))
            new_tokens = out[:, inputs["input_ids"].shape[1]:]
            return self._processor.batch_decode(new_tokens, skip_special_tokens=True,
                                                clean_up_tokenization_spaces=False)[0]

    # ------------------------------------------------------------------ one verdict
    async def ajudge(self, inp: JudgeInput) -> Verdict:
        aggregate = str(self._get("aggregate", "physical"))
        verdict = Verdict(judge=self.name, judge_model="TIGER-Lab/VideoScore2",
                          prompt_version=PROMPT_VERSION,
                          sampling=f"video at {float(self._get('infer_fps', 2.0)):g} fps "
                                   f"(generated clip only, no reference)")
        reason = self.unavailable_reason()
        if reason is not None:
            verdict.error = f"unavailable: {reason}"
            return verdict
        loop = asyncio.get_running_loop()
        start = loop.time()
        try:
            answer = await asyncio.to_thread(self._infer, inp.generated_video)
        except Exception as exc:  # noqa: BLE001 - a failed local inference is an invalid verdict
            verdict.error = " ".join(f"inference failed: {type(exc).__name__}: {exc}".split())[:500]
            verdict.error_kind = CallErrorKind.server.value  # may succeed next time: not cached
            verdict.latency_s = loop.time() - start
            return verdict
        verdict.latency_s = loop.time() - start
        verdict.transport_attempts = 1
        scores = parse_scores(answer)
        verdict.raw = json.dumps({"dimensions": scores, "aggregate": aggregate,
                                  "reply": answer})
        if scores is None:
            verdict.error = "no VideoScore2 scores (visual quality / text-to-video alignment / " \
                            "physical/common-sense consistency) in the reply"
            return verdict
        if not all(1 <= v <= 5 for v in scores.values()):
            verdict.error = f"VideoScore2 score outside 1–5: {scores}"
            return verdict
        s = (scores["physical_consistency"] if aggregate == "physical"
             else sum(scores.values()) / len(scores))
        verdict.score = round(to_ten(s), 4)
        verdict.valid = True
        verdict.justification = (f"VideoScore2 (1–5): visual quality {scores['visual_quality']}, "
                                 f"text-to-video alignment {scores['text_alignment']}, physical/"
                                 f"common-sense consistency {scores['physical_consistency']}; "
                                 f"{aggregate} mapped to 1–10")
        return verdict

    async def aclose(self) -> None:
        self._model = self._processor = None


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="judge", name="schema_videoscore2_judge",
                       node=VideoScore2JudgeConfig)


@hookimpl
def visphy_register_judges(register):
    register("videoscore2", VideoScore2Judge)
