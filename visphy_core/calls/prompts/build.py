"""Assemble the prompt a model sees for one scene, and the repair prompt after a failure.

Modes (config ``prompt``): paper-faithful (no timing information, the default), ``timed``
(states fps, clip length and the time between the two frames), with or without the detection
context, and forecast-only (only the first frame).

Every template is versioned in ``versions.json`` (version and SHA-256 of its text; a test fails
when a template changes without a new version). The version of a prompt names the templates it
was built from, e.g. ``default@2+spec_2d@1+detection@1``; it is stored with every reply and is
part of the response cache key.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from string import Template

from visphy_core.api.model import ImageInput
from visphy_core.api.scene import Scene
from visphy_core.infra.png import png_bytes

_DIR = Path(__file__).parent


def _template(name: str) -> Template:
    return Template((_DIR / f"{name}.txt").read_text())


@lru_cache(maxsize=1)
def template_versions() -> dict[str, dict]:
    """``{template name: {"version": int, "sha256": str}}`` from ``versions.json``."""
    return json.loads((_DIR / "versions.json").read_text())


def version_of(names: list[str]) -> str:
    """The prompt version of a prompt built from the named templates."""
    versions = template_versions()
    return "+".join(f"{name}@{versions[name]['version']}" for name in names)


@dataclass(frozen=True)
class PromptSettings:
    frames: tuple[int, ...] = (1, 10)  # 1-based key frames given to the model
    detection: bool = True
    forecast_only: bool = False
    timed: bool = False

    @classmethod
    def from_cfg(cls, cfg) -> "PromptSettings":
        return cls(frames=tuple(int(f) for f in cfg.frames), detection=bool(cfg.detection),
                   forecast_only=bool(cfg.forecast_only), timed=bool(cfg.timed))


def build_prompt(scene: Scene, engine_instructions: str, language: str,
                 settings: PromptSettings) -> tuple[str, list[ImageInput], str]:
    """Prompt text, key-frame images and the prompt version for one scene."""
    frames = settings.frames[:1] if settings.forecast_only else settings.frames
    images = [ImageInput(f"frame_{i:02d}", png_bytes(scene.key_frame(i))) for i in frames]
    if len(frames) == 1:
        sentence = (f"Image 1 is the first frame (frame {frames[0]}). Predict how the scene "
                    "evolves from it.")
    else:
        sentence = (f"Image 1 is frame {frames[0]} and image 2 is a later frame (frame "
                    f"{frames[1]}) of the same video.")
    used = ["default", f"spec_{scene.dim}"]
    if settings.timed:
        used.append("timing")
        fps, n = scene.clip.fps, scene.clip.n_frames
        later = frames[1] if len(frames) > 1 else frames[0]
        sentence += "\n" + _template("timing").substitute(
            fps=f"{fps:g}", n_frames=n, duration_s=f"{n / fps:g}", first_index=frames[0],
            later_index=later, gap_s=f"{(later - frames[0]) / fps:g}")
    detection_block = ""
    if settings.detection and scene.detection is not None:
        used.append("detection")
        detection_block = _template("detection").substitute(
            detection_json=json.dumps(scene.detection, indent=1))
    text = _template("default").substitute(
        frames_sentence=sentence, language=language, engine_instructions=engine_instructions,
        detection_block=detection_block,
        spec_format=_template(f"spec_{scene.dim}").template.rstrip("\n"))
    return text, images, version_of(used)


def build_repair_prompt(original: str, language: str, failed_program: str,
                        failure_class: str, error_summary: str, max_program_chars: int = 20000
                        ) -> str:
    """The original prompt plus the failing program and a concise error summary (its version
    is the original's plus ``+repair@N``: `repair_version`)."""
    program = failed_program
    if len(program) > max_program_chars:
        program = program[:max_program_chars] + "\n/* … truncated … */"
    return original + _template("repair").substitute(
        language=language, failed_program=program, failure_class=failure_class,
        error_summary=error_summary.strip() or "(no error text)")


def repair_version(original_version: str) -> str:
    return f"{original_version}+{version_of(['repair'])}"


def judge_prompt(input_kind: str, n_frames: int = 0, duration_s: float = 0.0
                 ) -> tuple[str, str]:
    """(text, version) of the judge prompt for video input or for sampled frames."""
    if input_kind == "video":
        return _template("judge_video").template, version_of(["judge_video"])
    text = _template("judge_frames").substitute(n_frames=n_frames, duration_s=f"{duration_s:g}")
    return text, version_of(["judge_frames"])


def reference_caption_prompt(n_frames: int, duration_s: float) -> tuple[str, str]:
    """(text, version) of the prompt that asks an LLM for a reference description."""
    text = _template("reference_caption").substitute(n_frames=n_frames,
                                                     duration_s=f"{duration_s:g}")
    return text, version_of(["reference_caption"])
