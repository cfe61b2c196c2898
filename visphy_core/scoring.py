"""Run the selected metrics on one scene's clips, with unavailable metrics reported as such.

The generated clip is brought to the reference contract first (fps, frame count, size) by its
own timestamps (`visphy_core.video.resample_by_time`), so frames are paired by time, never by
index across different frame rates. Values are cached by the
content of both clips and the metric's identity, so re-scoring never recomputes.
"""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np

from visphy_core.cache import Cache, content_key
from visphy_core.metrics import Metric, MetricInput
from visphy_core.scene import Scene
from visphy_core.video import resample_by_time, resize_with_padding


def clip_digest(frames: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(frames).tobytes()).hexdigest()


def to_contract(scene: Scene, generated: np.ndarray,
                generated_times_s: np.ndarray | None = None) -> np.ndarray:
    """``generated`` as the scene's clip (fps, frame count, size), paired by time.

    With ``generated_times_s`` (each frame's presentation time in seconds, e.g. from
    `visphy_core.video.decode_video_timed`) the frame shown at k / fps becomes frame k. Without
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


def score_scene(scene: Scene, reference: np.ndarray, generated: np.ndarray,
                metrics: list[Metric], analysis: str | None, spec: dict | None,
                cache: Cache, generated_times_s: np.ndarray | None = None,
                reference_text: str | None = None
                ) -> tuple[dict[str, float | None], dict[str, str]]:
    """Scores by metric name, and the reason for each metric that could not be computed.

    ``generated_times_s``: the generated frames' presentation times (seconds from its first
    frame) when the clip does not already follow the scene's contract (a foreign video).
    ``reference_text``: the scene's reference description, for text metrics.
    """
    if generated.shape != reference.shape or generated_times_s is not None:
        generated = to_contract(scene, generated, generated_times_s)
    inp = MetricInput(scene=scene, reference=reference, generated=generated, analysis=analysis,
                      spec=spec, reference_text=reference_text)
    clips = content_key(clip_digest(reference), clip_digest(generated), analysis or "",
                        json.dumps(spec, sort_keys=True) if spec else "", reference_text or "")
    scores: dict[str, float | None] = {}
    unavailable: dict[str, str] = {}
    for metric in metrics:
        reason = metric.unavailable_reason()
        if reason:
            scores[metric.name], unavailable[metric.name] = None, reason
            continue
        key = content_key("score", metric.name, metric.version, type(metric).__qualname__, clips)
        entry = cache.get("score", key)
        if entry is not None:
            value = json.loads((entry / "value.json").read_text())["value"]
        else:
            value = float(metric.compute(inp))
            if math.isnan(value):
                value = None
            cache.put("score", key, {"value.json": json.dumps({"value": value})})
        scores[metric.name] = value
    return scores, unavailable
