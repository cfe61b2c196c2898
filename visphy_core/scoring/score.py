"""Run the selected metrics on one scene's clips, with unavailable metrics reported as such.

The generated clip is brought to the reference contract first (fps, frame count, size) by its
own timestamps (`visphy_core.infra.video.resample_by_time`), so frames are paired by time, never by
index across different frame rates. Then each pairing of the `ScoringProtocol` is made once
(`visphy_core.scoring.alignment`) and every metric scored under it:

=====================  ========================================  ==========================
pairing                what is paired                            columns
=====================  ========================================  ==========================
visphy (unaligned)     every frame k with frame k (by time)      ``psnr``, ``flow_epe_dis``
visphy aligned         every frame, best single offset           ``psnr.aligned``, …,
                                                                  ``align.offset``,
                                                                  ``align.err``
paper                  every 3rd frame BY INDEX, upstream's       ``paper.psnr``, …,
                       offset step then DTW                       ``paper.align.offset``,
                       (`visphy_core.scoring.paper_protocol`)             ``paper.align.err``
=====================  ========================================  ==========================

The ``paper`` pairing follows upstream's ``evaluate_pair`` on the generated clip AS GIVEN (its
frames in decode order, stretched to the reference's size), not on the clip brought to the
contract by time: upstream reads no timestamps, so a clip at a foreign frame rate is paired by
index there (`paper_clip`). Its ``paper.psnr`` and ``paper.ssim`` are upstream's own frame
scores (`visphy_core.scoring.paper_protocol.FRAME_SCORES`), averaged over the pairs that gave a
number.

A ``scene`` metric (text, spec) has one column. Values are cached by the content of both clips,
the pairing and the metric's identity, so re-scoring never recomputes.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from visphy_core.api import weights
from visphy_core.api.metrics import HIGHER, LOWER, PAIRS, SCENE, Metric, MetricInput
from visphy_core.api.scene import Scene
from visphy_core.infra.cache import Cache, content_key
from visphy_core.infra.video import resample_by_time, resize_with_padding
from visphy_core.results.columns import SPEC_PREFIX, norm_column
from visphy_core.scoring import paper_protocol
from visphy_core.scoring.alignment import (
    EVERY_FRAME,
    PAPER,
    Alignment,
    AlignParams,
    align,
    unaligned,
)


def clip_digest(frames: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(frames).tobytes()).hexdigest()


def to_contract(scene: Scene, generated: np.ndarray,
                generated_times_s: np.ndarray | None = None) -> np.ndarray:
    """``generated`` as the scene's clip (fps, frame count, size), paired by time.

    With ``generated_times_s`` (each frame's presentation time in seconds, e.g. from
    `visphy_core.infra.video.decode_video_timed`) the frame shown at k / fps becomes frame k.
    Without
    them the clip must already have the contract's frame count (a render made to the contract):
    only its size is fitted; a different frame count is refused rather than paired by index.
    """
    c = scene.clip
    if generated_times_s is not None:
        times = np.asarray(generated_times_s, dtype=np.float64)
        on_grid = (len(generated) == c.n_frames
                   and np.allclose(times, np.arange(c.n_frames) / c.fps, rtol=0, atol=5e-4))
        if on_grid and generated.shape[1:3] == (c.height, c.width):
            return generated
        return resample_by_time(generated, times, c)
    if len(generated) != c.n_frames:
        raise ValueError(
            f"scene {scene.scene_id}: the generated clip has {len(generated)} frames, the "
            f"contract {c.n_frames}; pass its timestamps (generated_times_s) so frames are "
            "paired by time, not by index")
    if generated.shape[1:3] != (c.height, c.width):
        return np.stack([resize_with_padding(f, c.width, c.height) for f in generated])
    return generated


@dataclass(frozen=True)
class ScoringProtocol:
    """Which pairings every frame and sequence metric is scored under (``metrics.protocol``)."""

    unaligned: bool = True                 # visphy: every frame, by time (the plain column)
    aligned: bool = True                   # visphy: every frame, best offset (``.aligned``)
    paper: bool = True                     # the upstream protocol (``paper.``)
    aligned_params: AlignParams = EVERY_FRAME
    paper_params: AlignParams = PAPER
    spec_track: bool = False               # also score S simulated and replayed (``spec.``)
    variance_norm: bool = False            # variance-normalised columns (``norm.``)

    @classmethod
    def from_cfg(cls, cfg: Any) -> "ScoringProtocol":
        """From the ``metrics`` config node (``protocol``: ``[visphy, paper]`` or a subset;
        ``aligned``; ``paper.*`` and ``align.*`` overrides of the search parameters;
        ``spec_track``; ``variance_norm``)."""
        if cfg is None:
            return cls()
        names = [str(n) for n in (cfg.get("protocol") or ["visphy", "paper"])]
        visphy = "visphy" in names
        paper_over = dict(cfg.get("paper") or {})
        align_over = dict(cfg.get("align") or {})
        return cls(unaligned=visphy, aligned=visphy and bool(cfg.get("aligned", True)),
                   paper="paper" in names,
                   aligned_params=replace(EVERY_FRAME, **align_over),
                   paper_params=replace(PAPER, **paper_over),
                   spec_track=bool(cfg.get("spec_track", False)),
                   variance_norm=bool(cfg.get("variance_norm", False)))

    def views(self) -> list[str]:
        """The pairings in column order: ``""`` (unaligned), ``"aligned"``, ``"paper"``."""
        return ([""] if self.unaligned else []) + (["aligned"] if self.aligned else []) \
            + (["paper"] if self.paper else [])


def select_metrics(registry: Any, cfg: Any) -> list[Metric]:
    """The metrics of ``metrics.names`` (copies, with ``metrics.max_pairs`` applied), after
    pointing the weight search at ``metrics.weights_dir`` and models at ``metrics.device``."""
    weights.configure(cfg.get("weights_dir"), cfg.get("device") or "cpu")
    limits = dict(cfg.get("max_pairs") or {})
    out = []
    for name in cfg.names:
        metric = registry.get("metrics", name)
        if name in limits:
            metric = copy.copy(metric)
            metric.max_pairs = int(limits[name]) if limits[name] else None
        out.append(metric)
    return out


def column(metric_name: str, view: str) -> str:
    if view == "":
        return metric_name
    if view == "aligned":
        return f"{metric_name}.aligned"
    return f"{view}.{metric_name}"


def _align_columns(view: str) -> list[tuple[str, str]]:
    prefix = {"aligned": "align", "paper": "paper.align"}[view]
    return [(f"{prefix}.offset", LOWER), (f"{prefix}.err", LOWER)]




def score_columns(metrics: list[Metric], protocol: ScoringProtocol | None = None
                  ) -> list[tuple[str, str]]:
    """Every score column (name, direction) a run with these metrics writes, in order (with
    the spec track on: then its ``spec.``-prefixed frame and sequence metric columns; with
    normalisation on: then ``norm.<metric>`` and ``spec.norm.<metric>``, all ↑)."""
    protocol = protocol or ScoringProtocol()
    frame = [m for m in metrics if m.kind != SCENE]
    if protocol.variance_norm:

        plain = replace(protocol, variance_norm=False)
        prefixes = ("", SPEC_PREFIX) if protocol.spec_track else ("",)
        return score_columns(metrics, plain) + [
            (norm_column(p + m.name), HIGHER) for p in prefixes for m in frame]
    if protocol.spec_track:
        plain = replace(protocol, spec_track=False)
        return score_columns(metrics, plain) + [
            (SPEC_PREFIX + c, d) for c, d in score_columns(frame, plain)]
    views = protocol.views()
    cols: list[tuple[str, str]] = []
    for m in metrics:
        if m.kind == SCENE:
            cols.append((m.name, m.direction))
        else:
            cols += [(column(m.name, v), m.direction) for v in views]
    if any(m.kind != SCENE for m in metrics):
        for v in views:
            if v:
                cols += _align_columns(v)
    return cols


def paper_clip(reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
    """The generated clip as upstream's ``evaluate_pair`` reads it (``read_video_frames`` with
    ``resize_to`` the reference's size): every frame in decode order, by index (no timestamps),
    stretched to the reference's width×height by area interpolation. ``generated`` must be the
    clip as decoded, before `to_contract`."""
    return paper_protocol.fit_to_reference(generated, *reference.shape[1:3])


def alignments(reference: np.ndarray, generated: np.ndarray, protocol: ScoringProtocol,
               paper_generated: np.ndarray | None = None) -> dict[str, Alignment]:
    """Each view's pairing. ``paper_generated``: the clip the paper view pairs (`paper_clip`;
    default ``generated``); the paper view's indices point into it."""
    out = {}
    for v in protocol.views():
        if v == "":
            out[v] = unaligned(len(reference), len(generated))
        elif v == "aligned":
            out[v] = align(reference, generated, protocol.aligned_params)
        else:
            out[v] = align(reference, generated if paper_generated is None else paper_generated,
                           protocol.paper_params)
    return out


def score_scene(scene: Scene, reference: np.ndarray, generated: np.ndarray,
                metrics: list[Metric], analysis: str | None, spec: dict | None,
                cache: Cache, generated_times_s: np.ndarray | None = None,
                reference_text: str | None = None, protocol: ScoringProtocol | None = None,
                program: str | None = None, language: str | None = None,
                details: dict | None = None, as_decoded: np.ndarray | None = None
                ) -> tuple[dict[str, float | None], dict[str, str]]:
    """Scores by column, and the reason for each column that could not be computed.

    ``generated_times_s``: the generated frames' presentation times (seconds from its first
    frame) when the clip does not already follow the scene's contract (a foreign video).
    ``reference_text``: the scene's reference description, for text metrics.
    ``program``/``language``: the model's program, for metrics that read it (``needs``
    ``program``; only their cached values depend on it).
    ``details``: a dict filled with the metrics' per-scene breakdowns (`Metric.details`).
    ``as_decoded``: a foreign video's first frames in decode order (at least
    `paper_protocol.frames_needed`), when ``generated`` was already put on the contract's time
    grid: the ``paper`` view pairs these by index, as upstream does.
    """
    protocol = protocol or ScoringProtocol()
    as_given = generated if as_decoded is None else as_decoded
    if generated.shape != reference.shape or generated_times_s is not None:
        generated = to_contract(scene, generated, generated_times_s)
    inp = MetricInput(scene=scene, reference=reference, generated=generated, analysis=analysis,
                      spec=spec, reference_text=reference_text, program=program,
                      language=language)
    clips = content_key(clip_digest(reference), clip_digest(generated), analysis or "",
                        json.dumps(spec, sort_keys=True) if spec else "", reference_text or "")
    frame_metrics = any(m.kind != SCENE for m in metrics)
    paper_gen = _paper_generated(reference, as_given, generated, protocol.paper and frame_metrics)
    paper_inp, paper_clips = inp, clips
    if paper_gen is not generated:  # its own clip: own per-scene memo (indices differ)
        paper_inp = replace(inp, generated=paper_gen, extra={})
        paper_clips = content_key(clips, "paper-clip", clip_digest(paper_gen))
    views = alignments(reference, generated, protocol, paper_gen) if frame_metrics else {}
    scores: dict[str, float | None] = {}
    unavailable: dict[str, str] = {}
    for v, a in views.items():
        if v:
            (off_col, _), (err_col, _) = _align_columns(v)
            err = float(a.align_err)
            scores[off_col], scores[err_col] = float(a.offset), None if math.isnan(err) else err

    def cached(col: str, key_parts: tuple, fn, clips: str = clips) -> float | None:
        key = content_key("score", col, *key_parts, clips)
        if "program" in metric.needs:
            key = content_key(key, language or "", program or "")
        entry = cache.get("score", key)
        if entry is not None:
            return json.loads((entry / "value.json").read_text())["value"]
        value = float(fn())
        value = None if math.isnan(value) else value
        cache.put("score", key, {"value.json": json.dumps({"value": value})})
        return value

    for metric in metrics:
        cols = [metric.name] if metric.kind == SCENE else [column(metric.name, v) for v in views]
        reason = metric.unavailable_reason()
        if reason:
            for col in cols:
                scores[col], unavailable[col] = None, reason
            continue
        ident = (metric.name, metric.version, metric.identity())
        if metric.kind == SCENE:
            scores[metric.name] = cached(metric.name, ident, lambda: metric.compute(inp))
        elif metric.kind == PAIRS:
            memo: dict[tuple[int, int], float] = {}
            for v, a in views.items():
                if v == "paper":
                    scores[column(metric.name, v)] = cached(
                        column(metric.name, v), ident + (_pairs_key(a), _paper_key(metric)),
                        lambda a=a: _paper_mean_over_pairs(metric, reference, paper_gen, a,
                                                           memo if paper_gen is generated
                                                           else {}),
                        clips=paper_clips)
                    continue
                scores[column(metric.name, v)] = cached(
                    column(metric.name, v), ident + (_pairs_key(a),),
                    lambda a=a: _mean_over_pairs(metric, reference, generated, a, memo))
        else:
            # a view whose pairs are another view's on the same clip (the aligned view at
            # offset 0, the usual case for a good model) has that view's value: computed once
            done: dict[tuple[str, str], float | None] = {}
            for v, a in views.items():
                view_inp = paper_inp if v == "paper" else inp
                view_clips = paper_clips if v == "paper" else clips
                same = (_pairs_key(a), view_clips)
                if same in done:
                    scores[column(metric.name, v)] = done[same]
                    continue
                scores[column(metric.name, v)] = done[same] = cached(
                    column(metric.name, v), ident + (_pairs_key(a),),
                    lambda a=a, view_inp=view_inp: metric.compute_sequence(view_inp, a),
                    clips=view_clips)
    if details is not None:
        _collect_details(metrics, inp, details)
    return scores, unavailable


def _paper_generated(reference: np.ndarray, as_given: np.ndarray, generated: np.ndarray,
                     paper: bool) -> np.ndarray:
    """The generated clip the paper view pairs: the clip as given, by index (upstream reads no
    timestamps); ``generated`` itself when that is the same clip."""
    paper_gen = paper_clip(reference, as_given) if paper else generated
    if paper_gen is not generated and paper_gen.shape == generated.shape \
            and np.array_equal(paper_gen, generated):
        paper_gen = generated
    return paper_gen


def _collect_details(metrics: list[Metric], inp: MetricInput, details: dict) -> None:
    """Each available metric's per-scene breakdown into ``details`` (an error in one is
    recorded as its breakdown)."""
    for metric in metrics:
        if metric.unavailable_reason():
            continue
        try:
            info = metric.details(inp)
        except Exception as exc:  # noqa: BLE001 - a breakdown never costs the scores
            info = {"error": f"{type(exc).__name__}: {exc}"[:300]}
        if info is not None:
            details.setdefault(metric.details_key or metric.name, info)


def _pairs_key(a: Alignment) -> str:
    return hashlib.sha256(np.stack([a.ref_idx, a.gen_idx]).astype(np.int64).tobytes()
                          ).hexdigest()[:16]


def _paper_key(metric: Metric) -> str:
    """What the paper view's value of a pair metric depends on beyond visphy's: upstream's own
    frame score (psnr, ssim) or visphy's, and the version of the paper rules."""
    own = "upstream-score" if metric.name in paper_protocol.FRAME_SCORES else "visphy-score"
    return f"paper-rules:{paper_protocol.RULES_VERSION}/{own}"


def _paper_mean_over_pairs(metric: Metric, reference: np.ndarray, generated: np.ndarray,
                           a: Alignment, memo: dict[tuple[int, int], float]) -> float:
    """A pair metric under the paper view: upstream's own frame score where upstream computes
    one (psnr, ssim; the mean over the pairs that gave a number, as upstream's
    ``evaluate_pair`` averages them), otherwise visphy's metric on the paper's pairs."""
    own = paper_protocol.FRAME_SCORES.get(metric.name)
    if own is None:
        return _mean_over_pairs(metric, reference, generated, a, memo)
    pairs = subsample_pairs(a.pairs(), metric.max_pairs)
    if not pairs:
        return float("nan")
    values: dict[tuple[int, int], float] = {}
    for p in pairs:
        if p not in values:
            try:
                values[p] = own(reference[p[0]], generated[p[1]])
            except paper_protocol.FRAME_SCORE_ERRORS:  # upstream: NaN for an OpenCV failure
                values[p] = float("nan")
    return paper_protocol.mean_of_numbers(values[p] for p in pairs)


def subsample_pairs(pairs: list[tuple[int, int]], max_pairs: int | None
                    ) -> list[tuple[int, int]]:
    """At most ``max_pairs`` of ``pairs``, evenly spaced, first and last kept."""
    if max_pairs is None or len(pairs) <= max_pairs:
        return pairs
    if max_pairs <= 1:
        return pairs[:1]
    idx = np.unique(np.round(np.linspace(0, len(pairs) - 1, max_pairs)).astype(int))
    return [pairs[i] for i in idx]


def _mean_over_pairs(metric: Metric, reference: np.ndarray, generated: np.ndarray,
                     a: Alignment, memo: dict[tuple[int, int], float]) -> float:
    """The mean of a pair metric over an alignment's pairs (at most ``metric.max_pairs`` of
    them), each distinct pair computed once per scene (in one batch) and shared between the
    pairings."""
    pairs = subsample_pairs(a.pairs(), metric.max_pairs)
    if not pairs:
        return float("nan")
    todo = sorted({p for p in pairs if p not in memo})
    if todo:
        ri = np.array([r for r, _ in todo])
        gi = np.array([g for _, g in todo])
        values = np.asarray(metric.pair_values(reference[ri], generated[gi]), dtype=np.float64)
        memo.update(zip(todo, values.tolist()))
    return float(np.mean([memo[p] for p in pairs]))
