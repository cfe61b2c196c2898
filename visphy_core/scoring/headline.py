"""The headline physics score: one number per scene that a frozen first frame cannot win.

Error-magnitude metrics (pixels, flow, track velocity) rank "nothing moves" above real models:
predicting no motion costs less than predicting motion in a slightly wrong place. The headline
is built only from components that pass the validity suite (``benchmarks/validity_study.py``:
physics-right clips drawn differently > physics-wrong clips > a still clip and the flow
extrapolation), and each component is put on one scale by two anchors the scene itself sets:

* **floor** ``f``: what the first key frame held for the whole clip scores (the ``static``
  baseline, the run's fallback clip). It needs no spec, so it exists for every dataset,
  the original layout included;
* **ceiling** ``c``: what the ground truth's twin scores (`visphy_core.scoring.normalisation`: the
  physics re-simulated after an imperceptible nudge, replayed by the engine being evaluated)
  where the scene has a spec and normalisation is on; otherwise the metric's ideal value (the
  good end of its declared range: 1 for an IoU, 0 for an error).

A component's value ``m`` becomes ``(m − f) / (c − f)``, clipped to ``clip`` (default
[−1, 1]: a component cannot carry the mean alone), and the headline is the mean of the
components the scene defines (a component is undefined when it has no value, or when its
anchors do not separate: ``c`` not better than ``f``, e.g. a scene where nothing moves).
From that mean each **penalty** (``metrics.headline.penalties``: metric → weight) subtracts
weight × its value, and the result is clipped to ``clip`` again: a penalty is a metric a still
clip cannot fail (the default, ``body_area_drift``: drawn bodies that do not keep their size, a
still clip's being 0), so it has no floor to be normalised against. So a
still clip scores exactly 0 and the ground truth about 1, on every dataset.

The per-scene value is the score column ``<name>`` (``score_<name>`` in results tables); the
components, anchors and where each ceiling came from are in the scene's ``headline.json``;
``summary.json`` has ``"headline": {"metric", "mean", "ci", "n", "components", …}``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from visphy_core.api.headline import (
    CEILINGS,
    DEFAULT_CEILING,
    DEFAULT_COMPONENTS,
    DEFAULT_NAME,
    DEFAULT_PENALTIES,
)
from visphy_core.api.metrics import HIGHER, Metric

BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0


@dataclass(frozen=True)
class Headline:
    """What the headline is made of (``metrics.headline``)."""

    name: str = DEFAULT_NAME
    components: tuple[str, ...] = DEFAULT_COMPONENTS
    clip: tuple[float, float] = (-1.0, 1.0)
    ceiling: str = DEFAULT_CEILING
    #: (metric, weight): subtracted from the components' mean, weight × value
    penalties: tuple[tuple[str, float], ...] = tuple(DEFAULT_PENALTIES.items())

    @classmethod
    def from_cfg(cls, cfg: Any) -> "Headline | None":
        """From the ``metrics`` config node; None when ``metrics.headline.enabled`` is false or
        it names no component."""
        node = (cfg.get("headline") if cfg is not None else None) or {}
        if not node.get("enabled", True):
            return None
        components = tuple(str(c) for c in (node.get("components") or DEFAULT_COMPONENTS))
        if not components:
            return None
        clip = tuple(float(v) for v in (node.get("clip") or (-1.0, 1.0)))
        ceiling = node.get("ceiling") or DEFAULT_CEILING
        ceiling = str(getattr(ceiling, "value", ceiling))
        if ceiling not in CEILINGS:
            raise ValueError(f"metrics.headline.ceiling={ceiling}: one of {', '.join(CEILINGS)}")
        penalties = node.get("penalties")
        penalties = DEFAULT_PENALTIES if penalties is None else penalties
        weights = []
        for metric, weight in dict(penalties).items():
            weight = float(weight)
            if not (math.isfinite(weight) and weight >= 0):
                raise ValueError(f"metrics.headline.penalties.{metric}={weight}: a weight is a "
                                 "finite number ≥ 0")
            weights.append((str(metric), weight))
        return cls(name=str(node.get("name") or DEFAULT_NAME), components=components,
                   clip=(clip[0], clip[1]), ceiling=ceiling, penalties=tuple(weights))

    @classmethod
    def for_run(cls, cfg: Any, metrics: Iterable[Metric]) -> "Headline | None":
        """`from_cfg`, or None when none of its components is among the run's ``metrics``
        (``metrics.names=[psnr]``: no headline column, ``summary.json`` says why)."""
        headline = cls.from_cfg(cfg)
        return headline if headline is not None and headline.metrics_of(metrics) else None

    def metrics_of(self, metrics: Iterable[Metric]) -> list[Metric]:
        """The run's metrics that are components (in the components' order)."""
        by_name = {m.name: m for m in metrics}
        return [by_name[c] for c in self.components if c in by_name]

    def penalties_of(self, metrics: Iterable[Metric]) -> list[tuple[Metric, float]]:
        """The run's metrics that are penalties, each with its weight (zero weights left out)."""
        by_name = {m.name: m for m in metrics}
        return [(by_name[n], w) for n, w in self.penalties if n in by_name and w > 0]


def ideal(metric: Metric) -> float | None:
    """The metric's best possible value (the good end of its declared range), if finite."""
    lo, hi = metric.score_range
    value = hi if metric.direction == HIGHER else lo
    return float(value) if value is not None and math.isfinite(value) else None


def component(value: float | None, floor: float | None, ceiling: float | None, direction: str,
              clip: tuple[float, float]) -> tuple[float | None, str | None]:
    """(the clipped normalised value, None) or (None, why)."""
    if value is None or not math.isfinite(value):
        return None, "no value"
    if floor is None or ceiling is None or not (math.isfinite(floor) and math.isfinite(ceiling)):
        return None, "an anchor is undefined on this scene"
    gap = (ceiling - floor) if direction == HIGHER else (floor - ceiling)
    if not gap > 1e-9 * max(1.0, abs(floor), abs(ceiling)):
        return None, (f"the ceiling ({ceiling:.6g}) is not better than the still clip's "
                      f"{floor:.6g} on this scene")
    return float(min(max((value - floor) / (ceiling - floor), clip[0]), clip[1])), None


def scene_headline(headline: Headline, metrics: list[Metric], values: dict[str, float | None],
                   floor: dict[str, float | None], twin: dict[str, float | None]
                   ) -> tuple[float | None, dict]:
    """The scene's headline value and its details (``headline.json``). ``twin``: what the
    ground truth's twin scored (empty without a twin: the ideal values are the ceilings).
    The mean of the defined components, less each penalty's weight × value (a penalty without a
    value subtracts nothing and says why), clipped to ``headline.clip``; None when no component
    is defined."""
    parts: dict[str, dict] = {}
    used = []
    twin = twin if headline.ceiling == "twin" else {}
    for m in headline.metrics_of(metrics):
        top, source = twin.get(m.name), "twin"
        if top is None:
            top, source = ideal(m), "ideal"
        norm, why = component(values.get(m.name), floor.get(m.name), top, m.direction,
                              headline.clip)
        parts[m.name] = {"value": values.get(m.name), "floor": floor.get(m.name),
                         "ceiling": top, "ceiling_from": source, "normalised": norm}
        if why:
            parts[m.name]["undefined"] = why
        else:
            used.append(norm)
    penalties: dict[str, dict] = {}
    value = float(np.mean(used)) if used else None
    for m, weight in headline.penalties_of(metrics):
        v = values.get(m.name)
        entry: dict = {"value": v, "weight": weight}
        if v is None or not math.isfinite(v):
            entry["undefined"] = "no value"
        else:
            entry["subtracted"] = weight * v
            if value is not None:
                value -= weight * v
        penalties[m.name] = entry
    for name, weight in headline.penalties:
        if weight > 0 and name not in penalties:
            penalties[name] = {"value": None, "weight": weight,
                               "undefined": "not among the run's metrics (metrics.names)"}
    if value is not None:
        value = float(min(max(value, headline.clip[0]), headline.clip[1]))
    out = {"metric": headline.name, "value": value, "clip": list(headline.clip),
           "ceiling": headline.ceiling,
           "floor": "the first key frame held (the static baseline / fallback clip)",
           "components": parts}
    if penalties:
        out["penalties"] = penalties
    return value, out


def bootstrap_ci(values: list[float], level: float = 0.95) -> list[float] | None:
    """The percentile bootstrap interval of the mean over scenes (seeded: same values, same
    interval); None for fewer than two values."""
    if len(values) < 2:
        return None
    arr = np.asarray(values, dtype=np.float64)
    idx = np.random.default_rng(BOOTSTRAP_SEED).integers(0, len(arr),
                                                         size=(BOOTSTRAP_RESAMPLES, len(arr)))
    means = arr[idx].mean(axis=1)
    tail = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [tail, 1.0 - tail])
    return [float(lo), float(hi)]


def summary_entry(headline: Headline, success: list[float], with_fallbacks: list[float]) -> dict:
    """``summary.json``'s ``headline``: the mean over model successes and over every scored
    scene (fallbacks count 0), each with its 95% bootstrap interval and count."""
    def block(vals: list[float]) -> tuple[float | None, list[float] | None, int]:
        return (float(np.mean(vals)) if vals else None), bootstrap_ci(vals), len(vals)

    mean, ci, n = block(with_fallbacks)
    ok_mean, ok_ci, ok_n = block(success)
    return {"metric": headline.name, "direction": HIGHER, "mean": mean, "ci": ci, "n": n,
            "view": "all scored scenes (a fallback clip scores 0)",
            "mean_model_success": ok_mean, "ci_model_success": ok_ci, "n_model_success": ok_n,
            "components": list(headline.components), "ceiling": headline.ceiling,
            "penalties": dict(headline.penalties), "small_sample": n < 10}
