"""One scene through the pipeline: prompt → model → extract → validate → render → repair →
fallback → score. Every outcome, failures included, becomes one `SceneResult` row.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from visphy_core.api.engine import (
    Engine,
    FailureClass,
    Program,
    ProgramRejected,
    RenderContract,
    classify_frames,
)
from visphy_core.api.extract import extract_analysis, extract_spec
from visphy_core.api.metrics import Metric
from visphy_core.api.model import (
    ImageInput,
    Model,
    ModelRequest,
    ModelResponse,
    OutputContract,
    build_model_request,
)
from visphy_core.api.scene import Scene
from visphy_core.calls.generation import ModelCaller
from visphy_core.calls.judging import JudgeCaller
from visphy_core.calls.prompts.build import (
    PromptSettings,
    build_prompt,
    build_repair_prompt,
    repair_version,
)
from visphy_core.calls.references import ReferenceWriter
from visphy_core.calls.usage import CostCapReached
from visphy_core.execute.engine_references import EngineReferenceClips
from visphy_core.execute.render_cache import (  # noqa: F401 - re-exported for callers
    RENDER_FLAGS,
    UNCACHED_FAILURES,
    RenderOutcome,
    render_cached,
    render_key,
)
from visphy_core.infra.cache import Cache
from visphy_core.infra.errors import SceneDataError, UserError, host_fault, one_line
from visphy_core.infra.events import StageEvents
from visphy_core.infra.secrets import redact
from visphy_core.infra.video import decode_video, encode_video, frame_digest, load_clip_for
from visphy_core.results import layout
from visphy_core.results.row import SceneResult
from visphy_core.results.write import write_artifact
from visphy_core.scoring.headline import Headline
from visphy_core.scoring.paper_protocol import frames_needed
from visphy_core.scoring.reference_clips import frozen_clip
from visphy_core.scoring.scene_scores import (
    ScoringServices,
    score_columns_of,
    score_outputs,
    write_scores,
)
from visphy_core.scoring.score import ScoringProtocol
from visphy_core.spec.reply_spec import spec_problems


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


_write = write_artifact


def mark_not_evaluable(result: SceneResult, failure: FailureClass, detail: str) -> None:
    """Mark a scene that could not be evaluated (data_error / infra_error): no clip, no scores."""
    result.model_success = result.system_success = result.fallback = False
    result.failure_class = failure.value
    result.failure_detail = redact(one_line(detail))[:2000]
    if result.first_failure_class is None:
        result.first_failure_class = failure.value
    result.frame_digests = []
    result.scores = {name: None for name in result.scores}
    result.unavailable = {}


@dataclass
class SceneServices:
    """What every scene of a run shares: the model behind its caller, the engine, the metrics,
    the judges, the reference writer, the settings, the cache, and who hears of each stage's
    progress."""

    model: Model
    caller: ModelCaller
    engine: Engine
    metrics: list[Metric]
    settings: PipelineSettings
    cache: Cache
    judges: JudgeCaller | None = None
    references: ReferenceWriter | None = None
    protocol: ScoringProtocol = field(default_factory=ScoringProtocol)
    progress: StageEvents = field(default_factory=StageEvents)
    headline: Headline | None = None
    # the ground-truth store (`visphy_core.scoring.ground_truth`)
    ground_truth: Cache | None = None

    def scoring(self, renders: dict[str, RenderOutcome] | None = None) -> ScoringServices:
        """The scoring half (`visphy_core.scoring.scene_scores`): reference-program clips rendered
        by
        this run's engine (``renders``: the scene's clips so far, `render_cached`'s memo)."""
        return ScoringServices(metrics=self.metrics, cache=self.cache, protocol=self.protocol,
                               clips=EngineReferenceClips(self.engine, self.cache,
                                                          self.progress, renders,
                                                          self.ground_truth),
                               judges=self.judges, references=self.references,
                               progress=self.progress, headline=self.headline,
                               ground_truth=self.ground_truth)


class ProviderRejectedKey(UserError):
    """The provider refused the key (HTTP 401/403): every scene would fail the same way."""


@dataclass
class FirstCall:
    """The first prompt of a scene and the request built from it."""

    prompt: str
    images: list[ImageInput]
    version: str
    request: ModelRequest


def first_call(scene: Scene, services: SceneServices) -> FirstCall:
    """The scene's first prompt and request: the pipeline and the run's prefetch build the same
    request, so a prefetched call is the one the pipeline asks for."""
    s, engine = services.settings, services.engine
    prompt, images, version = build_prompt(scene, engine.instructions(scene.dim), engine.language,
                                           s.prompt)
    return FirstCall(prompt, images, version, _request(scene, services, prompt, images, version,
                                                       attempt=1))


def _request(scene: Scene, services: SceneServices, prompt: str, images: list[ImageInput],
             version: str, attempt: int) -> ModelRequest:
    c = scene.clip
    return build_model_request(
        services.model, scene=scene, engine=services.engine, scene_id=scene.scene_id,
        prompt=prompt, images=images, engine_name=services.engine.name,
        detection=scene.detection if services.settings.prompt.detection else None,
        language=services.engine.language, output=OutputContract(c.fps, c.n_frames, c.width,
                                                                 c.height),
        attempt=attempt, prompt_version=version, stage="generate" if attempt == 1 else "repair")


def process_scene(scene: Scene, services: SceneServices, scene_dir: Path) -> SceneResult:
    """Run one scene end to end and write its artifacts under ``scene_dir``.

    Never raises for a fault of this scene: a bad input of the scene is a ``data_error`` row
    (checked before the model is called), any other exception an ``infra_error`` row with the
    exception type and message. A fault of the machine (`host_fault`: a full disk, a read-only
    or forbidden folder) is raised: it is no scene's, and the run stops, resumable. Raises
    `CostCapReached` (the run stops before this scene; it is redone on resume) and
    `ProviderRejectedKey` (every scene would fail). `BaseException`s that are not
    `Exception`s (an interrupted run, Ctrl-C) propagate.
    """
    columns = score_columns_of(services.scoring())
    result = SceneResult(scene_id=scene.scene_id, dim=scene.dim, difficulty=scene.difficulty,
                         output_kind=services.model.output_kind,
                         scores={name: None for name in columns})  # same columns for every row
    try:
        settings = services.settings
        frames = (settings.prompt.frames[:1] if settings.prompt.forecast_only
                  else settings.prompt.frames)
        reference = scene.check_inputs(tuple(frames) or (1,))
        _evaluate(scene, reference, services, scene_dir, result)
    except (CostCapReached, ProviderRejectedKey):
        raise
    except SceneDataError as exc:
        mark_not_evaluable(result, FailureClass.DATA_ERROR, str(exc))
    except Exception as exc:  # noqa: BLE001 - one scene's fault never aborts the run
        if host_fault(exc) is not None:  # but a full disk is every scene's: the run stops
            raise
        mark_not_evaluable(result, FailureClass.INFRA_ERROR, f"{type(exc).__name__}: {exc}")
    try:
        write_scores(scene_dir, result)
        _write(scene_dir / layout.FRAMES_META, json.dumps(
            {"fps": scene.clip.fps, "n_frames": scene.clip.n_frames, "width": scene.clip.width,
             "height": scene.clip.height, "frame_digests": result.frame_digests}, indent=1))
    except OSError as exc:
        if host_fault(exc) is not None:
            raise
        if result.failure_class is None or result.evaluable:
            mark_not_evaluable(result, FailureClass.INFRA_ERROR, f"{type(exc).__name__}: {exc}")
    return result


def _model_error(result: SceneResult, response: ModelResponse, attempt: int,
                 model: Model) -> None:
    if response.error_kind == "auth":
        raise ProviderRejectedKey(f"model={model.name}: the provider refused the key in "
                                  f"${model.needs_key} ({response.error}); check the key")
    result.failure_class = FailureClass.MODEL_ERROR.value
    result.failure_detail = redact(one_line(response.error or ""))[:2000]
    if attempt == 1:
        result.first_failure_class = result.failure_class


def _reply_failure(response: ModelResponse, exc: ProgramRejected) -> tuple[FailureClass, str]:
    """The class of a reply the engine could not use, informed by why the reply ended."""
    if response.finish_reason in ("refusal", "content_filter") and exc.failure in (
            FailureClass.NO_CODE, FailureClass.WRONG_LANGUAGE):
        return FailureClass.REFUSAL, (f"the model refused ({response.finish_reason}): "
                                      f"{response.refusal or response.text[:300]}")
    if response.truncated and exc.failure is not FailureClass.TRUNCATED:
        return FailureClass.TRUNCATED, (f"the reply hit the output token limit "
                                        f"({response.usage.get('output_tokens', '?')} tokens): "
                                        f"{exc}")
    return exc.failure, str(exc)


def _record_spec(result: SceneResult, spec: dict | None, dim: str, scene_dir: Path,
                 attempt: int) -> None:
    if spec is None:
        result.spec_valid, result.spec_problems = None, []
        return
    problems = spec_problems(spec, dim)
    result.spec_valid, result.spec_problems = not problems, problems
    _write(scene_dir / layout.attempt_file(layout.SPEC, attempt, "json"),
           json.dumps(spec, indent=1))
    _write(scene_dir / layout.attempt_file(layout.SPEC_VALIDATION, attempt, "json"),
           json.dumps({"valid": not problems, "problems": problems}, indent=1))


def _prompt_record(first: FirstCall, engine: Engine, model) -> dict:
    """What ``prompt.json`` says of the scene's first call."""
    return {"text": first.prompt, "images": [i.name for i in first.images], "engine": engine.name,
            "prompt_version": first.version, "privileged": model.privileged}


def _record_response(result: SceneResult, response: ModelResponse, cached: bool,
                     scene_dir: Path, attempt: int) -> None:
    """Count one reply's usage into the row and write it (``response.txt`` / ``.json`` of the
    attempt)."""
    result.response_cached = cached
    result.model_calls += 0 if cached else 1
    result.model_latency_s += response.latency_s
    result.cost_usd += response.cost_usd or 0.0
    result.input_tokens += int(response.usage.get("input_tokens", 0) or 0)
    result.output_tokens += int(response.usage.get("output_tokens", 0) or 0)
    result.finish_reason = response.finish_reason
    _write(scene_dir / layout.attempt_file(layout.RESPONSE, attempt, "txt"), response.text)
    _write(scene_dir / layout.attempt_file(layout.RESPONSE, attempt, "json"), json.dumps(
        {k: getattr(response, k) for k in ("usage", "cost_usd", "latency_s", "error",
                                            "error_kind", "finish_reason", "refusal",
                                            "transport_attempts", "prompt_version",
                                            "model_id")} | {"cached": cached}, indent=1))


def _evaluate(scene: Scene, reference: np.ndarray, services: SceneServices, scene_dir: Path,
              result: SceneResult) -> None:
    model, engine, settings = services.model, services.engine, services.settings
    contract = RenderContract.for_scene(scene, timeout_s=settings.timeout_s, seed=settings.seed)
    first = first_call(scene, services)
    result.prompt_version = first.version
    _write(scene_dir / layout.PROMPT, json.dumps(_prompt_record(first, engine, model), indent=1))
    outcome: RenderOutcome | None = None
    clip: np.ndarray | None = None
    decoded: np.ndarray | None = None   # a video reply's frames by index (the paper protocol)
    request = first.request
    analysis, spec = None, None
    program: Program | None = None
    attempts = (1, 2) if settings.retry and model.output_kind == "program" else (1,)
    renders: dict[str, RenderOutcome] = {}  # this scene's clips, by render key
    for attempt in attempts:
        result.attempts = attempt
        with services.progress.stage("generate", scene.scene_id):
            response, cached = services.caller.call(request)
        _record_response(result, response, cached, scene_dir, attempt)
        if response.error:
            if response.error_kind == "not_recorded" and attempt > 1:
                break  # a replay without the repair reply: the first failure stands
            _model_error(result, response, attempt, model)
            break
        analysis = extract_analysis(response.text)
        spec = extract_spec(response.text)
        if model.output_kind == "program":
            _record_spec(result, spec, scene.dim, scene_dir, attempt)
        if model.output_kind == "video":
            if response.video_path and Path(response.video_path).is_file():
                # the model's own video, byte for byte: a replay of this run starts from it
                _write(scene_dir / layout.attempt_file(layout.REPLY, attempt, "mp4"),
                       Path(response.video_path).read_bytes())
            clip, decoded, failure, detail = _video_reply(response, scene, services.protocol)
            if clip is not None:
                break
            failed_source, logs = response.text, []
        else:
            try:
                program = engine.extract(response.text)
                engine.validate(program)
            except ProgramRejected as exc:
                failure, detail = _reply_failure(response, exc)
                failed_source, logs = response.text, []
                _set_render_flags(result, [])  # this attempt rendered nothing
            else:
                ext = "html" if program.language == "html" else "py"
                _write(scene_dir / layout.attempt_file(layout.PROGRAM, attempt, ext),
                       program.source)
                with services.progress.stage("render", scene.scene_id):
                    outcome = render_with_infra_retry(engine, program, contract,
                                                      services.cache, scene_dir, attempt,
                                                      result, services.progress, renders)
                if outcome.failure is None:
                    break
                failure, detail, failed_source, logs = (outcome.failure, outcome.error or "",
                                                        program.source, outcome.logs)
                outcome = None
        result.failure_class, result.failure_detail = failure.value, redact(detail)
        if attempt == 1:
            result.first_failure_class = failure.value
        if not failure.blames_program or attempt == attempts[-1]:
            break  # no repair call for our own or the provider's failures
        repair = redact(build_repair_prompt(first.prompt, engine.language, failed_source,
                                            failure.value, error_summary(detail, logs)))
        _write(scene_dir / layout.REPAIR_PROMPT, repair)
        request = _request(scene, services, repair, first.images,
                           repair_version(first.version), attempt=2)
    if analysis is not None:
        _write(scene_dir / layout.ANALYSIS, analysis)

    if outcome is not None or clip is not None:
        result.model_success = result.system_success = True
        result.failure_class = result.failure_detail = None
        generated = _write_clip(result, outcome, clip, scene_dir, contract)
    elif result.failure_class == FailureClass.INFRA_ERROR.value:
        # Not evaluable (our side failed twice): no fallback clip, nothing counted for the model.
        result.scores = {name: None for name in result.scores}
        return
    elif settings.fallback:
        # Fallback: the first key frame held for the whole clip ("nothing moves"). It uses only
        # what the model was given, keeps every metric defined, and is never a model success.
        result.fallback = result.system_success = True
        generated = frozen_clip(scene, contract, scene_dir / layout.VIDEO)
    else:
        generated = None
    score_outputs(scene, reference, generated, analysis, spec, services.scoring(renders),
                  scene_dir, result, contract, program if outcome is not None else None,
                  spec_track=model.output_kind == "program",
                  as_decoded=decoded if clip is not None and outcome is None else None)


def _write_clip(result: SceneResult, outcome: RenderOutcome | None, clip: np.ndarray | None,
                scene_dir: Path, contract: RenderContract) -> np.ndarray:
    """The scene's clip (the rendered program's, else the model's video) written as
    ``video.mp4``; its frames, with their digests and a static-output flag in the row."""
    if outcome is not None:
        generated = outcome.frames
        result.frame_digests = outcome.frame_digests
        _write(scene_dir / layout.VIDEO, outcome.video_path.read_bytes())
    else:
        encode_video(clip, scene_dir / layout.VIDEO, contract.fps)
        generated = decode_video(scene_dir / layout.VIDEO)[0]
        result.frame_digests = [frame_digest(f) for f in generated]
    flag = classify_frames(generated)
    if flag is FailureClass.STATIC_OUTPUT:
        result.flags.append(flag.value)
    return generated


def render_with_infra_retry(engine: Engine, program: Program, contract: RenderContract,
                            cache: Cache, scene_dir: Path, attempt: int,
                            result: SceneResult,
                            progress: StageEvents | None = None,
                            renders: dict[str, RenderOutcome] | None = None) -> RenderOutcome:
    outcome = render_cached(engine, program, contract, cache, renders)
    log_lines = []
    if outcome.failure is FailureClass.INFRA_ERROR:
        # Our side failed, not the program: render once more (never cached, so this is a
        # real second render), with no repair call to the model. Not when the run is closing
        # (its engine may be what failed).
        (progress or StageEvents()).check()
        result.infra_retries += 1
        log_lines += [f"infra_error (retrying the render once): {outcome.error or ''}",
                      *outcome.logs, "--- retry ---"]
        outcome = render_cached(engine, program, contract, cache, renders)
    partial = layout.attempt_file(layout.PARTIAL, attempt, "mp4")
    _write(scene_dir / layout.attempt_file(layout.RENDER_LOG, attempt, "log"), "\n".join(
        [*log_lines, f"failure: {outcome.failure.value if outcome.failure else 'none'}",
         f"isolation: {outcome.isolation or 'unknown'}",
         f"flags: {', '.join(outcome.flags) or 'none'}",
         *([f"partial clip: {partial}"] if outcome.partial_path else []),
         f"error: {outcome.error or ''}", *outcome.logs]))
    if outcome.partial_path is not None:
        _write(scene_dir / partial, outcome.partial_path.read_bytes())
    result.render_cached = outcome.cached
    result.render_wall_s = outcome.wall_s
    result.isolation = outcome.isolation
    _set_render_flags(result, outcome.flags)
    return outcome


def _set_render_flags(result: SceneResult, flags: list[str]) -> None:
    """The row's render flags are those of its last render (the program the row reports)."""
    result.flags = [f for f in result.flags if f not in RENDER_FLAGS]
    result.flags += [f for f in flags if f in RENDER_FLAGS and f not in result.flags]


def _video_reply(response: ModelResponse, scene: Scene, protocol: ScoringProtocol
                 ) -> tuple[np.ndarray | None, np.ndarray | None, FailureClass, str]:
    """A pixel-space model's clip, resampled to the reference by its own timestamps, and (for
    the ``paper`` protocol, which pairs by index) its first decoded frames as they are."""
    if not response.video_path:
        return None, None, FailureClass.NO_CODE, "the video model returned no video"
    keep: list | None = [] if protocol.paper else None
    need = frames_needed(scene.clip.n_frames, protocol.paper_params.sample_every,
                         protocol.paper_params.max_offset)
    try:
        clip = load_clip_for(Path(response.video_path), scene.clip, keep_decoded=keep,
                             keep_max=need)
    except (ValueError, OSError) as exc:
        return None, None, FailureClass.BLANK_OUTPUT, \
            f"unreadable video: {one_line(str(exc))}"
    if classify_frames(clip) is FailureClass.BLANK_OUTPUT:
        return None, None, FailureClass.BLANK_OUTPUT, \
            "every frame of the video is one flat colour"
    return clip, (np.stack(keep) if keep else None), FailureClass.BLANK_OUTPUT, ""

