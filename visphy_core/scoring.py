"""Run the selected metrics on one scene's clips, with unavailable metrics reported as such.

The generated clip is normalised to the reference contract first (fps, frame count, size), so
frames are paired by time, never by index across different frame rates. Values are cached by the
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
from visphy_core.video import normalise_clip


def _clip_digest(frames: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(frames).tobytes()).hexdigest()


def score_scene(scene: Scene, reference: np.ndarray, generated: np.ndarray,
                metrics: list[Metric], analysis: str | None, spec: dict | None,
                cache: Cache) -> tuple[dict[str, float | None], dict[str, str]]:
    """Scores by metric name, and the reason for each metric that could not be computed."""
    if generated.shape != reference.shape:
        generated = normalise_clip(generated, scene.clip.fps, scene.clip)
    inp = MetricInput(scene=scene, reference=reference, generated=generated, analysis=analysis,
                      spec=spec)
    clips = content_key(_clip_digest(reference), _clip_digest(generated), analysis or "",
                        json.dumps(spec, sort_keys=True) if spec else "")
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
