"""One leaderboard row per run: what a reader compares runs by, read once from the run.

The headline (``summary.json``'s ``headline``: ``physics_score`` by default) is taken in the
run's own headline view, every scored scene with a fallback clip scoring as the fallback does
(`visphy_core.analysis.column_views.WITH_FALLBACKS`), with the interval the run itself reports; a
run whose summary has no headline block gets both recomputed from its rows. The metric
families are the plain pairing's metrics grouped by their declared family, each metric placed
on a 0..1-ish scale where higher is better (its variance-normalised mean when the run has one:
0 = the still clip, 1 = the ground truth's twin; else its mean's place in its declared range),
then averaged per family.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from visphy_core.analysis.bootstrap import resample_indices
from visphy_core.analysis.column_views import WITH_FALLBACKS, scene_values
from visphy_core.report.column_groups import direction_of, group_of
from visphy_core.results.load import RunData

DEFAULT_HEADLINE = "physics_score"
#: ``vpb3-s0-2d-t001-v00`` → ``t001``: the benchmark's template, shared by a scene's variants.
TEMPLATE = re.compile(r"(?:^|[-_])(t\d+)(?:[-_]|$)")


def finite(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def template_of(scene_id: str) -> str | None:
    """The template a scene id names (``t001``), or None."""
    match = TEMPLATE.search(str(scene_id))
    return match.group(1) if match else None


def slugify(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-.")[:60] or "run"


@dataclass
class Entry:
    """One measured row: a run under its comparison label."""

    run: RunData
    label: str
    slug: str
    dataset: str
    metric: str
    mean: float | None
    ci: tuple[float, float] | None
    n: int
    #: the headline per scene (scene id → value), in the headline's view
    values: pd.Series
    families: dict[str, float] = field(default_factory=dict)

    @property
    def model(self) -> str:
        return self.run.model

    @property
    def engine(self) -> str:
        return self.run.engine

    def stat(self, *keys: str, default: Any = None) -> Any:
        """A value of ``summary.json`` by path (``usage``, ``all``, ``cost_usd``)."""
        node: Any = self.run.summary
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                return default
            node = node[key]
        return node

    @property
    def model_success_rate(self) -> float | None:
        return finite(self.stat("model_success_rate"))

    @property
    def system_success_rate(self) -> float | None:
        return finite(self.stat("system_success_rate"))

    @property
    def cost_usd(self) -> float | None:
        return finite(self.stat("usage", "all", "cost_usd"))

    @property
    def tokens(self) -> int | None:
        usage = self.stat("usage", "all", default={}) or {}
        if not usage:
            return None
        return int(usage.get("input_tokens") or 0) + int(usage.get("output_tokens") or 0)

    def seconds(self, stage: str) -> float | None:
        return finite(self.stat("stage_seconds", stage, "total"))

    @property
    def date(self) -> str:
        started = str(self.run.manifest.get("started") or "")
        return started[:10] or self.run.name[:10]

    @property
    def version(self) -> str:
        return str(self.run.manifest.get("visphy_version") or "")

    @property
    def dims(self) -> str:
        dims = sorted({str(d).upper() for d in self.run.table.get("dim", pd.Series()).dropna()})
        return "+".join(dims)


def headline_metric(run: RunData) -> str:
    return str((run.summary.get("headline") or {}).get("metric") or DEFAULT_HEADLINE)


def percentile_ci(values: np.ndarray, level: float = 0.95) -> tuple[float, float] | None:
    """The seeded percentile bootstrap interval of the mean (None under two values)."""
    if len(values) < 2:
        return None
    means = values[resample_indices(len(values))].mean(axis=1)
    lo, hi = np.quantile(means, [(1 - level) / 2, 1 - (1 - level) / 2])
    return float(lo), float(hi)


def family_scores(summary: dict) -> dict[str, float]:
    """Per metric family, the mean place of its plain-pairing metrics (higher is better)."""
    metrics = summary.get("metrics") or {}
    info = summary.get("metric_info") or {}
    head = (summary.get("headline") or {}).get("metric")
    places: dict[str, list[float]] = {}
    for name, entry in metrics.items():
        if group_of(name) != "visphy" or name == head or not isinstance(entry, dict):
            continue
        meta = info.get(name) if isinstance(info.get(name), dict) else {}
        family = str(meta.get("family") or "other")
        norm = finite((metrics.get(f"norm.{name}") or {}).get("mean_model_success"))
        place = norm
        mean = finite(entry.get("mean_model_success"))
        rng = meta.get("range")
        if place is None and mean is not None and isinstance(rng, (list, tuple)) \
                and len(rng) == 2:
            lo, hi = finite(rng[0]), finite(rng[1])
            if lo is not None and hi is not None and hi > lo:
                frac = (mean - lo) / (hi - lo)
                place = frac if direction_of(name, summary) != "lower" else 1 - frac
        if place is not None:
            places.setdefault(family, []).append(place)
    return {family: float(np.mean(v)) for family, v in sorted(places.items())}


def make_entry(run: RunData, label: str, index: int) -> Entry:
    """The row of ``run`` (labelled ``label``; ``index`` keeps slugs unique)."""
    metric = headline_metric(run)
    values = scene_values(run, metric, WITH_FALLBACKS)
    values = values[~values.index.duplicated(keep="last")]
    head = run.summary.get("headline") or {}
    mean, ci, n = finite(head.get("mean")), head.get("ci"), int(head.get("n") or 0)
    if mean is None:
        arr = values.to_numpy(np.float64)
        mean = float(arr.mean()) if len(arr) else None
        ci, n = percentile_ci(arr), len(arr)
    interval = None
    if isinstance(ci, (list, tuple)) and len(ci) == 2 and None not in (finite(ci[0]),
                                                                       finite(ci[1])):
        interval = (float(ci[0]), float(ci[1]))
    dataset = str(run.cfg("dataset.name") or run.summary.get("dataset") or "?")
    return Entry(run=run, label=label, slug=f"{index:02d}-{slugify(label)}", dataset=dataset,
                 metric=metric, mean=mean, ci=interval, n=n, values=values,
                 families=family_scores(run.summary))
