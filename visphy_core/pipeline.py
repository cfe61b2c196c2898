"""One scene through the pipeline: prompt → model → extract → validate → render → repair →
fallback → score. Every outcome, failures included, becomes one `SceneResult` row.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from visphy_core.cache import Cache, content_key
from visphy_core.engine import (Engine, FailureClass, Program, ProgramRejected, RenderContract,
                                classify_frames)
from visphy_core.extract import extract_analysis
from visphy_core.metrics import Metric
from visphy_core.model import Model, ModelRequest, ModelResponse
from visphy_core.prompts.build import PromptSettings, build_prompt, build_repair_prompt
from visphy_core.scene import Scene
from visphy_core.scoring import score_scene
from visphy_core.video import decode_video, encode_video, frame_digest


@dataclass
class SceneResult:
    """One row of results.parquet."""

    scene_id: str
    dim: str
    difficulty: str | None
    model_success: bool = False    # the model's own program (first or repaired) gave a clip
    system_success: bool = False   # a clip exists, counting the fallback
    fallback: bool = False
    attempts: int = 0
    failure_class: str | None = None     # why the last model attempt failed (None on success)
    failure_detail: str | None = None
    first_failure_class: str | None = None  # why the first attempt failed (retry ablation)
    flags: list[str] = field(default_factory=list)
    response_cached: bool = False
    render_cached: bool = False
    render_wall_s: float | None = None
    model_latency_s: float = 0.0
    cost_usd: float = 0.0
    frame_digests: list[str] = field(default_factory=list)
    scores: dict[str, float | None] = field(default_factory=dict)
    unavailable: dict[str, str] = field(default_factory=dict)

    def row(self) -> dict:
        d = asdict(self)
        scores = d.pop("scores")
        d.pop("unavailable")
        d["flags"] = ",".join(self.flags)
        d["frame_digests"] = json.dumps(self.frame_digests)
        for name, value in scores.items():
            d[f"score_{name}"] = value
        return d


@dataclass
class RenderOutcome:
    frames: np.ndarray | None
    failure: FailureClass | None
    error: str | None
    logs: list[str]
    frame_digests: list[str]
    video_path: Path | None
    cached: bool
    wall_s: float


def render_cached(engine: Engine, program: Program, contract: RenderContract,
                  cache: Cache) -> RenderOutcome:
    """Render through the content-addressed cache; failures are cached too (a program that
    timed out once times out again)."""
    key = content_key("render", engine.cache_identity(), program.digest, contract.key())
    entry = cache.get("render", key)
    if entry is None:
        result = engine.render(program, contract)
        meta = {"failure": result.failure.value if result.failure else None, "error": result.error,
                "logs": result.logs[-200:], "wall_s": result.wall_s,
                "frame_digests": [frame_digest(f) for f in result.frames]
                if result.frames is not None else []}
        files: dict = {"meta.json": json.dumps(meta, indent=1)}
        if result.frames is not None:
            tmp_video = cache.root / "tmp" / f"{key}.mp4"
            encode_video(result.frames, tmp_video, contract.fps)
            files["video.mp4"] = tmp_video
        entry = cache.put("render", key, files)
        if result.frames is not None:
            tmp_video.unlink(missing_ok=True)
        cached = False
    else:
        cached = True
    meta = json.loads((entry / "meta.json").read_text())
    video = entry / "video.mp4"
    frames = decode_video(video)[0] if video.is_file() else None
    failure = FailureClass(meta["failure"]) if meta["failure"] else None
    return RenderOutcome(frames=frames, failure=failure, error=meta["error"], logs=meta["logs"],
                         frame_digests=meta["frame_digests"],
                         video_path=video if video.is_file() else None, cached=cached,
                         wall_s=meta["wall_s"])


def call_model_cached(model: Model, request: ModelRequest, cache: Cache
                      ) -> tuple[ModelResponse, bool]:
    key = request.cache_key(model.identity())
    entry = cache.get("response", key)
    if entry is not None:
        data = json.loads((entry / "response.json").read_text())
        return ModelResponse(**data), True
    response = model.generate(request)
    if response.error is None:  # provider errors are not cached: a later run may succeed
        cache.put("response", key, {"response.json": json.dumps(asdict(response), default=str)})
    return response, False


def error_summary(outcome_error: str | None, logs: list[str], max_lines: int = 12) -> str:
    """Concise error text for the repair prompt: the error, then the last lines of the log."""
    lines = [outcome_error or ""] + [line for line in logs if line != outcome_error][-max_lines:]
    return "\n".join(line[:400] for line in lines if line)


@dataclass
class PipelineSettings:
    prompt: PromptSettings
    retry: bool = True
    fallback: bool = True
    timeout_s: float = 60.0
    seed: int = 0


def _write(path: Path, content: str | bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(content.encode() if isinstance(content, str) else content)
    tmp.replace(path)


def process_scene(scene: Scene, model: Model, engine: Engine, metrics: list[Metric],
                  settings: PipelineSettings, cache: Cache, scene_dir: Path) -> SceneResult:
    """Run one scene end to end and write its artifacts under ``scene_dir``."""
    result = SceneResult(scene_id=scene.scene_id, dim=scene.dim, difficulty=scene.difficulty,
                         scores={m.name: None for m in metrics})  # same columns for every row
    contract = RenderContract.for_scene(scene, timeout_s=settings.timeout_s, seed=settings.seed)
    prompt, images = build_prompt(scene, engine.instructions(scene.dim), engine.language,
                                  settings.prompt)
    _write(scene_dir / "prompt.json", json.dumps(
        {"text": prompt, "images": [i.name for i in images], "engine": engine.name}, indent=1))
    outcome: RenderOutcome | None = None
    text_prompt = prompt
    analysis, spec = None, None
    for attempt in (1, 2) if settings.retry else (1,):
        result.attempts = attempt
        request = ModelRequest(scene_id=scene.scene_id, prompt=text_prompt, images=images,
                               detection=scene.detection if settings.prompt.detection else None,
                               engine_name=engine.name, attempt=attempt, scene=scene,
                               engine=engine)
        response, cached = call_model_cached(model, request, cache)
        result.response_cached = cached
        result.model_latency_s += response.latency_s
        result.cost_usd += response.cost_usd or 0.0
        suffix = "" if attempt == 1 else f".attempt{attempt}"
        _write(scene_dir / f"response{suffix}.txt", response.text)
        if response.error:
            result.failure_class = FailureClass.MODEL_ERROR.value
            result.failure_detail = response.error
            break
        analysis = extract_analysis(response.text)
        try:
            program = engine.extract(response.text)
            spec = program.spec
            engine.validate(program)
        except ProgramRejected as exc:
            failure, detail, failed_source, logs = exc.failure, str(exc), response.text, []
        else:
            _write(scene_dir / f"program{suffix}.{'html' if program.language == 'html' else 'py'}",
                   program.source)
            outcome = render_cached(engine, program, contract, cache)
            _write(scene_dir / f"render{suffix}.log", "\n".join(
                [f"failure: {outcome.failure.value if outcome.failure else 'none'}",
                 f"error: {outcome.error or ''}", *outcome.logs]))
            result.render_cached = outcome.cached
            result.render_wall_s = outcome.wall_s
            if outcome.failure is None:
                break
            failure, detail, failed_source, logs = (outcome.failure, outcome.error or "",
                                                    program.source, outcome.logs)
            outcome = None
        result.failure_class, result.failure_detail = failure.value, detail
        if attempt == 1:
            result.first_failure_class = failure.value
        text_prompt = build_repair_prompt(prompt, engine.language, failed_source, failure.value,
                                          error_summary(detail, logs))
    if analysis is not None:
        _write(scene_dir / "analysis.txt", analysis)
    if spec is not None:
        _write(scene_dir / "spec.json", json.dumps(spec, indent=1))

    reference = scene.reference_frames()
    if outcome is not None:
        result.model_success = result.system_success = True
        result.failure_class = result.failure_detail = None
        generated = outcome.frames
        result.frame_digests = outcome.frame_digests
        _write(scene_dir / "video.mp4", outcome.video_path.read_bytes())
        flag = classify_frames(generated)
        if flag is FailureClass.STATIC_OUTPUT:
            result.flags.append(flag.value)
    elif settings.fallback:
        # Fallback: the first key frame held for the whole clip ("nothing moves"). It uses only
        # what the model was given, keeps every metric defined, and is never a model success.
        result.fallback = result.system_success = True
        generated = np.repeat(scene.key_frame(1)[None], contract.n_frames, axis=0)
        encode_video(generated, scene_dir / "video.mp4", contract.fps)
        generated = decode_video(scene_dir / "video.mp4")[0]
    else:
        generated = None
    if generated is not None:
        scores, unavailable = score_scene(scene, reference, generated, metrics, analysis, spec,
                                          cache)
        result.scores, result.unavailable = scores, unavailable
    _write(scene_dir / "scores.json", json.dumps(
        {"scores": result.scores, "unavailable": result.unavailable,
         "fallback": result.fallback}, indent=1))
    _write(scene_dir / "frames_meta.json", json.dumps(
        {"fps": contract.fps, "n_frames": contract.n_frames, "width": contract.width,
         "height": contract.height, "frame_digests": result.frame_digests}, indent=1))
    return result
