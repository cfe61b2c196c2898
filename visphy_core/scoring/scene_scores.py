"""Scoring one scene's outputs: metrics, judges, the spec track and variance normalisation.

Shared by the pipeline (right after a scene's clip is made) and by re-scoring
(`visphy_core.execute.rescore`: a finished run directory scored again with other metrics or judges),
so both write the same columns, the same per-scene files and hit the same cache entries.

The only step that differs is where the trusted reference program's clips come from (S replayed
for the spec track, the ground truth's twin for normalisation): a run renders them with its
engine, re-scoring reads them back from the run directory and never renders. `ReferenceClips`
is that seam.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from visphy_core.api.engine import RenderContract
from visphy_core.api.judge import JudgeInput
from visphy_core.api.metrics import SCENE, Metric
from visphy_core.api.scene import Scene
from visphy_core.calls.judging import JudgeCaller
from visphy_core.calls.references import ReferenceWriter
from visphy_core.infra.cache import Cache, content_key
from visphy_core.infra.events import StageEvents
from visphy_core.results import layout
from visphy_core.results.columns import SPEC_PREFIX, norm_column
from visphy_core.results.write import write_artifact
from visphy_core.scoring.ground_truth import scene_anchors
from visphy_core.scoring.headline import Headline, scene_headline
from visphy_core.scoring.normalisation import normalised, perturbation
from visphy_core.scoring.reference_clips import ReferenceClips, ReferenceClipUnavailable
from visphy_core.scoring.score import ScoringProtocol, clip_digest, score_columns, score_scene

if TYPE_CHECKING:
    from visphy_core.api.engine import Program
    from visphy_core.results.row import SceneResult


@dataclass
class ScoringServices:
    """What scoring a scene needs: metrics, protocol, cache, judges, the reference writer, where
    reference-program clips come from, and the progress listener."""

    metrics: list[Metric]
    cache: Cache
    protocol: ScoringProtocol
    clips: ReferenceClips
    judges: JudgeCaller | None = None
    references: ReferenceWriter | None = None
    progress: StageEvents = field(default_factory=StageEvents)
    headline: Headline | None = None
    #: the ground-truth store (`visphy_core.scoring.ground_truth`): normalisation anchors and the
    #: twin's render, shared by every run of the data dir; None: the run cache only
    ground_truth: Cache | None = None


def score_columns_of(services: ScoringServices) -> list[str]:
    """Every score column a row gets (the same for every row of a run): the headline first,
    judges last."""
    columns = [services.headline.name] if services.headline is not None else []
    columns += [name for name, _ in score_columns(services.metrics, services.protocol)]
    if services.judges is not None:
        columns += [services.judges.column(k) for k, _ in services.judges.judges]
    return columns


def score_outputs(scene: Scene, reference: np.ndarray, generated: np.ndarray | None,
                  analysis: str | None, spec: dict | None, services: ScoringServices,
                  scene_dir: Path, result: "SceneResult", contract: RenderContract,
                  program: "Program | None" = None, spec_track: bool = True,
                  as_decoded: np.ndarray | None = None) -> None:
    """Score a scene's clip (when there is one), then the spec track (when ``spec_track``: a
    program-writing model) and normalisation, as the protocol asks; then judge the clip.

    The scoring is one ``score`` stage and the judges come last, in a ``judge`` stage of their
    own: a run's worker gives its slot back while the judges answer."""
    with services.progress.stage("score", scene.scene_id):
        start = time.perf_counter()  # once the stage is entered (a worker slot is free)
        rendered = getattr(services.clips, "render_s", 0.0)
        own: dict[str, float | None] = {}
        if generated is not None:
            own = _score(scene, reference, generated, analysis, spec, services, scene_dir,
                         result, program, as_decoded)
        if services.protocol.spec_track and spec_track:
            services.progress.check()
            _spec_track(scene, reference, spec, result.spec_valid, services, scene_dir,
                        result, contract, generated, own)
        anchors: tuple[dict, dict] | None = None
        # a fallback clip is the frozen clip (`frozen_clip`): not made twice
        frozen = generated if result.fallback else None
        if services.protocol.variance_norm:
            services.progress.check()
            anchors = _normalise(scene, reference, services, scene_dir, result, contract,
                                 frozen)
        if services.headline is not None:
            _headline(scene, reference, generated, services, scene_dir, result, contract,
                      frozen, anchors)
        references = getattr(services.clips, "render_s", 0.0) - rendered
        result.reference_render_wall_s = round(references, 4)
        result.scoring_wall_s = round(time.perf_counter() - start - references, 4)
    if generated is not None and services.judges is not None:
        with services.progress.stage("judge", scene.scene_id):
            start = time.perf_counter()
            _judge(scene, reference, generated, services, scene_dir, result)
            result.judge_wall_s = round(time.perf_counter() - start, 4)


#: What a frame or sequence metric may read besides the two clips for `_spec_track` to reuse
#: its value on the generated clip (anything else, e.g. the model's S, could change it).
_CLIP_ONLY_NEEDS = frozenset({"frames", "scene_spec"})


def _spec_track(scene: Scene, reference: np.ndarray, spec: dict | None,
                spec_valid: bool | None, services: ScoringServices, scene_dir: Path,
                result: "SceneResult", contract: RenderContract,
                generated: np.ndarray | None = None,
                own: dict[str, float | None] | None = None) -> None:
    """Score S apart from the program: simulated by visphy, replayed by the engine's reference
    program, scored under the same protocol with ``spec.``-prefixed columns.

    When S replayed gives exactly the model's own clip (a program that is the reference program
    of its S, e.g. a privileged model's), a metric that reads only the clips has the value it
    already has on that clip: it is taken from ``own`` instead of being computed again."""
    if spec is None or spec_valid is None:
        result.spec_track = "no_spec"
        return
    if not spec_valid:
        result.spec_track = "invalid_spec"
        return
    try:
        frames = services.clips.spec_replay(scene, spec, contract, scene_dir)
    except ReferenceClipUnavailable as exc:
        result.spec_track, result.spec_track_error = "failed", str(exc)
        return
    metrics = [m for m in services.metrics if m.kind != SCENE]
    protocol = replace(services.protocol, spec_track=False)
    scores: dict[str, float | None] = {}
    unavailable: dict[str, str] = {}
    same_clip = (own and generated is not None and frames.shape == generated.shape
                 and np.array_equal(frames, generated))
    reused = [m for m in metrics if same_clip and set(m.needs) <= _CLIP_ONLY_NEEDS]
    if reused:
        names = {name for name, _ in score_columns(reused, protocol)}
        scores = {k: v for k, v in own.items() if k in names}
        unavailable = {k: v for k, v in result.unavailable.items() if k in names}
    rest = [m for m in metrics if m not in reused]
    if rest or not reused:
        more, why = score_scene(scene, reference, frames, rest, None, None, services.cache,
                                protocol=protocol)
        scores.update(more)
        unavailable.update(why)
    result.spec_track = "rendered"
    order = [name for name, _ in score_columns(metrics, protocol)]
    result.scores.update({f"{SPEC_PREFIX}{k}": scores[k] for k in order if k in scores})
    result.unavailable.update({f"{SPEC_PREFIX}{k}": v for k, v in unavailable.items()})


def _normalise(scene: Scene, reference: np.ndarray, services: ScoringServices, scene_dir: Path,
               result: "SceneResult", contract: RenderContract,
               frozen: np.ndarray | None = None) -> tuple[dict, dict] | None:
    """``norm.`` columns: each frame/sequence metric between the frozen clip (0) and the
    ground truth's twin (1), visphy_core.scoring.normalisation; the anchors in normalisation.json.
    Returns what the frozen clip and the twin scored (None when there was no twin)."""
    metrics = [m for m in services.metrics if m.kind != SCENE]
    targets = [c for c in (m.name for m in metrics) if c in result.scores] + [
        SPEC_PREFIX + m.name for m in metrics if SPEC_PREFIX + m.name in result.scores]
    if not targets:
        return None
    direction = {m.name: m.direction for m in metrics}

    def unavailable(why: str) -> None:
        for col in targets:
            result.scores[norm_column(col)] = None
            result.unavailable[norm_column(col)] = why

    try:
        found = scene_anchors(scene, reference, metrics, services.clips, contract,
                              services.cache, services.ground_truth, scene_dir, frozen=frozen)
    except ReferenceClipUnavailable as exc:
        unavailable(str(exc))
        return None
    floor, ceiling = found.floor, found.ceiling
    why_f, why_c = found.why_floor, found.why_ceiling
    anchors = {}
    for col in targets:
        base = col[len(SPEC_PREFIX):] if col.startswith(SPEC_PREFIX) else col
        why = why_c.get(base) or why_f.get(base)
        if why:
            result.scores[norm_column(col)] = None
            result.unavailable[norm_column(col)] = why
            continue
        value, reason = normalised(result.scores.get(col), floor.get(base), ceiling.get(base),
                                   direction[base])
        result.scores[norm_column(col)] = value
        anchors[base] = {"floor": floor.get(base), "ceiling": ceiling.get(base)}
        if reason and not col.startswith(SPEC_PREFIX):
            anchors[base]["undefined"] = reason
    twin_file = scene_dir / layout.TWIN_VIDEO
    write_artifact(scene_dir / layout.NORMALISATION, json.dumps(
        {"perturbation": perturbation(),
         "twin_video": twin_file.name if twin_file.is_file() else None,
         "twin_key": found.twin_key,
         "floor": "the first key frame held (the fallback clip)",
         "pairing": "visphy (unaligned)",
         "anchors_from": ("computed now" if found.computed else "stored")
         + (f" ({found.computed} value(s) scored now)" if found.computed else
            " (ground-truth store or cache: nothing scored now)"),
         "anchors": anchors}, indent=1))
    return ({k: v for k, v in floor.items() if k not in why_f},
            {k: v for k, v in ceiling.items() if k not in why_c})


def _headline(scene: Scene, reference: np.ndarray, generated: np.ndarray | None,
              services: ScoringServices, scene_dir: Path, result: "SceneResult",
              contract: RenderContract, frozen: np.ndarray | None,
              anchors: tuple[dict, dict] | None) -> None:
    """The headline column (`visphy_core.scoring.headline`): its components between the still clip
    and the twin (or the ideal values), from the anchors normalisation already scored where it
    did, else the still clip scored here on the components alone (cached like every score)."""
    headline = services.headline
    components = headline.metrics_of(services.metrics)
    if generated is None or not components:
        result.scores[headline.name] = None
        result.unavailable[headline.name] = ("no clip to score" if generated is None else
                                             "none of its components is in the run's metrics")
        return
    floor, twin = anchors if anchors is not None else ({}, {})
    missing = [m for m in components if m.name not in floor]
    if missing:
        found = scene_anchors(scene, reference, missing, services.clips, contract,
                              services.cache, services.ground_truth, None, ceiling=False,
                              frozen=frozen)
        floor = {**floor, **{k: v for k, v in found.floor.items() if k not in found.why_floor}}
    value, details = scene_headline(headline, services.metrics, result.scores, floor, twin)
    result.scores[headline.name] = value
    if value is None:
        result.unavailable[headline.name] = "no component is defined on this scene"
    write_artifact(scene_dir / layout.HEADLINE, json.dumps(details, indent=1))


def _score(scene: Scene, reference: np.ndarray, generated: np.ndarray,
           analysis: str | None, spec: dict | None, services: ScoringServices,
           scene_dir: Path, result: "SceneResult", program: "Program | None" = None,
           as_decoded: np.ndarray | None = None) -> dict[str, float | None]:
    """The metrics on the scene's own clip; returns their scores (also in ``result``)."""
    reference_text = None
    if services.references is not None:
        reference_text, result.reference_source = services.references.describe(scene)
        write_artifact(scene_dir / layout.REFERENCE, reference_text)
    details: dict = {}
    scores, unavailable = score_scene(scene, reference, generated, services.metrics, analysis,
                                      spec, services.cache, reference_text=reference_text,
                                      protocol=services.protocol,
                                      program=program.source if program else None,
                                      language=program.language if program else None,
                                      details=details, as_decoded=as_decoded)
    if details:
        write_artifact(scene_dir / layout.METRIC_DETAILS,
                       json.dumps(details, indent=1, default=str))
    result.scores.update(scores)
    result.unavailable.update(unavailable)
    return scores


def _judge(scene: Scene, reference: np.ndarray, generated: np.ndarray,
           services: ScoringServices, scene_dir: Path, result: "SceneResult") -> None:
    """Every judge's verdict on the scene's clip against the ground truth."""
    inp = JudgeInput(scene_id=scene.scene_id, dim=scene.dim, reference_video=scene.video_path,
                     generated_video=scene_dir / layout.VIDEO, fps=scene.clip.fps,
                     n_frames=scene.clip.n_frames)
    verdicts = services.judges.judge_scene(inp, content_key(clip_digest(reference),
                                                            clip_digest(generated)))
    for key, verdict in verdicts.items():
        column = services.judges.column(key)
        result.scores[column] = verdict.score if verdict.valid else None
        if not verdict.valid:
            result.judge_errors[key] = verdict.error or "invalid verdict"
            result.unavailable[column] = verdict.error or "invalid verdict"
    write_artifact(scene_dir / layout.VERDICTS, json.dumps(
        {k: v.to_json() for k, v in verdicts.items()}, indent=1, default=str))


def write_scores(scene_dir: Path, result: "SceneResult") -> None:
    """``scores.json``: the row's scores and why any is missing."""
    write_artifact(scene_dir / layout.SCORES, json.dumps(
        {"scores": result.scores, "unavailable": result.unavailable,
         "fallback": result.fallback, "failure_class": result.failure_class}, indent=1))
