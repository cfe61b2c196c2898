"""The validity study's goals measured: the summary ``benchmarks/validity_study.py
--order`` writes (``--summary``, default ``visphy_core/api/validity_summary.json``) and the
metric registry (`visphy_core.api.validity`), the docs' generated pages and the tests read.

Per score — the headline, and every frame and sequence metric — `study_summary` holds:

* **strict** / **means** (`order.summarise_order`, raw values in the score's good
  direction): the share of scenes where every (i) clip > every (ii) clip whose trajectory
  departs from the truth's by ≥ `MIN_PX` (20 px; `ClipScore.visible`: a (ii) clip that leaves a
  body out always counts) > both baselines (``strict``), or mean (i) > mean (ii) > max of the
  baselines (``means``); ``strict_any_px`` / ``means_any_px`` count every (ii) clip that differs
  from the truth at all. In 3D the 20 px are the same projected image pixels
  (`interventions.deviation` projects the bodies' positions through the scene's camera): what
  the clip shows, and what every metric sees, on the same 512-px frames as 2D;
* **invariance** (`invariance`): per restyle (the (i) variants), the median over scenes of
  |score(restyle) − score(truth clip)| on the headline's scale; ``max_median`` over the
  restyles (the goal: ≤ `INVARIANCE`);
* **physics drop** (`physics_drop`): per intervention, the median over the scenes where its clip
  departs by ≥ `MIN_PX` of score(truth clip) − score(intervention); ``min_median`` over the
  interventions (the goal: ≥ `DROP`);
* **monotone** (`dose.monotone_summary`): the share of (scene, dose series) cases where
  the score falls with the dose (ρ ≤ −0.9), per series, and the share of scenes where every
  series does.

"The headline's scale": the headline as it is; a metric as a one-component headline (floor:
the static clip's value, ceiling: the twin's, clipped to the headline's ``clip``), so that a
metric's invariance and drop read in the same units as the headline's (its ordering and
monotonicity are on its raw values: the same up to clipping).

``scenes``: one row per scene (`scene_rows`: strict? means? monotone share, worst restyle
delta, smallest ≥ 20 px physics drop, on the headline). ``discriminative_power``
(`power_summary`): how large a difference in mean headline a paired bootstrap over scenes
separates at 95 % (`discriminative_power`), from the per-scene headlines of pairs of variants
of one kind.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Callable, Iterable

import numpy as np

from visphy_core.api.metrics import HIGHER, Metric
from visphy_core.api.scoring import Headline, scene_headline
from visphy_plugins.studies.validity.clips import RIGHT, STATIC, WRONG, ClipScore, SceneOrder
from visphy_plugins.studies.validity.dose import (
    MONOTONE_RHO,
    monotone_summary,
    series_rho,
)
from visphy_plugins.studies.validity.dose import monotone as is_monotone
from visphy_plugins.studies.validity.interventions import INTERVENTIONS
from visphy_plugins.studies.validity.order import order_of, summarise_order
from visphy_plugins.studies.validity.restyles import APPEARANCES

MIN_PX = 20.0            # a (ii) clip this far from the truth is clearly wrong
STRICT_SHARE = 0.9       # strict ordering on ≥ 90 % of scenes
INVARIANCE = 0.05        # each restyle moves the headline by ≤ 0.05 (median over scenes)
DROP = 0.2               # each ≥ 20 px intervention lowers it by ≥ 0.2 (median over scenes)
MONOTONE_SHARE = 0.9     # monotone in the dose on ≥ 90 % of scenes
POWER_SCENES = (49, 209)  # the test split, the sub split
POWER_LEVEL = 0.95
POWER_RESAMPLES = 2000
POWER_SEED = 0

Scale = Callable[[SceneOrder, ClipScore], "float | None"]


def _ok(v: float | None) -> bool:
    return v is not None and math.isfinite(v)


def _floor(res: SceneOrder) -> dict[str, float | None]:
    static = next((c for c in res.clips if c.kind == STATIC), None)
    return static.scores if static is not None else res.floor


def headline_scale(metric: Metric, headline: Headline | None = None) -> Scale:
    """``metric`` on the headline's scale: a one-component headline (floor: the static clip,
    ceiling: the twin's value, else the metric's ideal; clipped like ``headline``)."""
    one = dataclasses.replace(headline or Headline(), name=metric.name,
                              components=(metric.name,))

    def scale(res: SceneOrder, c: ClipScore) -> float | None:
        return scene_headline(one, [metric], c.scores, _floor(res), res.twin)[0]
    return scale


def scales(metrics: Iterable[Metric], headline: Headline | None = None
           ) -> dict[str, tuple[str, Callable[[ClipScore], float | None], Scale]]:
    """Per score (``headline`` first, then each metric): (its direction, its raw value of a
    clip, its value on the headline's scale)."""
    headline = headline or Headline()
    out: dict[str, tuple] = {"headline": (HIGHER, lambda c: c.headline,
                                          lambda res, c: c.headline)}
    for m in metrics:
        out[m.name] = (m.direction, lambda c, n=m.name: c.scores.get(n),
                       headline_scale(m, headline))
    return out


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def invariance(results: list[SceneOrder], scale: Scale) -> dict:
    """Per restyle ((i) variant): the median over scenes of |score − the truth clip's score|
    (``median_abs``), the signed median (``median``, restyle − truth) and the scenes;
    ``max_median`` (the largest ``median_abs``) and which restyle (``worst``)."""
    deltas: dict[str, list[float]] = {}
    for res in results:
        ref = scale(res, res.truth) if res.truth is not None else None
        if not _ok(ref):
            continue
        for c in res.clips:
            v = scale(res, c) if c.kind == RIGHT else None
            if _ok(v):
                deltas.setdefault(c.name, []).append(v - ref)
    per = {n: {"median_abs": _median([abs(d) for d in ds]), "median": _median(ds),
               "scenes": len(ds)} for n, ds in deltas.items()}
    worst = max(per, key=lambda n: per[n]["median_abs"], default=None)
    return {"per_restyle": per, "max_median": per[worst]["median_abs"] if worst else None,
            "worst": worst}


def physics_drop(results: list[SceneOrder], scale: Scale, min_px: float = MIN_PX) -> dict:
    """Per intervention ((ii) variant): over the scenes where its clip departs by ≥ ``min_px``,
    the median of the truth clip's score − its score (``median``) and the scenes;
    ``min_median`` (the smallest) and which intervention (``weakest``)."""
    drops: dict[str, list[float]] = {}
    for res in results:
        ref = scale(res, res.truth) if res.truth is not None else None
        if not _ok(ref):
            continue
        for c in res.clips:
            v = scale(res, c) if c.kind == WRONG and c.visible(min_px) else None
            if _ok(v):
                drops.setdefault(c.name, []).append(ref - v)
    per = {n: {"median": _median(ds), "scenes": len(ds)} for n, ds in drops.items()}
    weakest = min(per, key=lambda n: per[n]["median"], default=None)
    return {"per_intervention": per, "min_median": per[weakest]["median"] if weakest else None,
            "weakest": weakest, "min_px": min_px}


def _share(row: dict, key: str) -> dict:
    return {"scenes": row["scenes"], "ordered": row[f"ordered_{key}"],
            "share": row[f"share_{key}"]}


def score_summary(results: list[SceneOrder], metrics: list[Metric],
                  headline: Headline | None = None, min_px: float = MIN_PX) -> dict[str, dict]:
    """Per score (``headline`` and each metric): strict, means (≥ ``min_px`` and every (ii)
    clip), monotone, invariance and physics drop, and whether each goal is met."""
    headline = headline or Headline()
    clear = summarise_order(results, metrics, headline, min_px=min_px)
    every = summarise_order(results, metrics, headline, min_px=0.0)
    out = {}
    for name, (direction, raw, scale) in scales(metrics, headline).items():
        mono = monotone_summary(results, raw, direction)
        inv = invariance(results, scale)
        drop = physics_drop(results, scale, min_px)
        strict, means = _share(clear[name], "strict"), _share(clear[name], "means")
        out[name] = {
            "name": headline.name if name == "headline" else name, "direction": direction,
            "strict": strict, "means": means,
            "strict_any_px": _share(every[name], "strict"),
            "means_any_px": _share(every[name], "means"),
            "monotone": mono, "invariance": inv, "physics_drop": drop,
            "goals_met": {
                "strict": _at_least(strict["share"], STRICT_SHARE),
                "invariance": None if inv["max_median"] is None
                else inv["max_median"] <= INVARIANCE,
                "physics_drop": _at_least(drop["min_median"], DROP),
                "monotone": _at_least(mono["share"], MONOTONE_SHARE)}}
    return out


def _at_least(v: float | None, goal: float) -> bool | None:
    return None if v is None else v >= goal


def scene_rows(results: list[SceneOrder], min_px: float = MIN_PX) -> list[dict]:
    """One row per scene, on the headline: ``strict`` / ``means`` (None: undefined),
    ``monotone`` (the share of its counted dose series where the headline falls with the dose;
    None: none counts), ``worst_restyle`` (the largest |restyle − truth|, and which),
    ``smallest_drop`` (the smallest truth − intervention over the ≥ ``min_px`` (ii) clips, and
    which), the truth clip's headline and the seconds the scene took."""
    rows = []
    for res in results:
        def of(kind: str, px: float = 0.0) -> list[ClipScore]:
            return [c for c in res.clips if c.kind == kind and c.visible(px)
                    and _ok(c.headline)]

        right, wrong = of(RIGHT), of(WRONG, min_px)
        base = [c.headline for c in res.clips if c.kind not in (RIGHT, WRONG)]
        order = order_of([c.headline for c in right], [c.headline for c in wrong], base,
                         HIGHER)
        rhos = series_rho(res, lambda c: c.headline)
        ref = res.truth.headline if res.truth is not None else None
        worst = max(right, key=lambda c: abs(c.headline - ref), default=None) \
            if _ok(ref) else None
        weakest = min(wrong, key=lambda c: ref - c.headline, default=None) \
            if _ok(ref) else None
        rows.append({
            "scene": res.scene_id, "dim": res.dim,
            "strict": None if order is None else order[1],
            "means": None if order is None else order[0],
            "monotone": (sum(is_monotone(r) for r in rhos.values()) / len(rhos)) if rhos
            else None,
            "series_rho": rhos,
            "worst_restyle": None if worst is None else abs(worst.headline - ref),
            "worst_restyle_name": None if worst is None else worst.name,
            "smallest_drop": None if weakest is None else ref - weakest.headline,
            "smallest_drop_name": None if weakest is None else weakest.name,
            "truth_headline": ref, "seconds": res.seconds})
    return rows


# --------------------------------------------------------------- discriminative power
def discriminative_power(a: Iterable[float | None], b: Iterable[float | None] | None = None, *,
                         sd: Iterable[float] | None = None, n_scenes: int | None = None,
                         level: float = POWER_LEVEL, resamples: int = POWER_RESAMPLES,
                         seed: int = POWER_SEED) -> float | None:
    """The smallest difference in mean score over ``n_scenes`` scenes that a paired bootstrap
    over scenes separates at ``level``: the half-width of the percentile interval of the mean
    paired difference, its spread taken from per-scene differences centred on their mean (so a
    systematic gap does not count as noise). A larger true difference gives an interval that
    leaves out 0.

    ``a``, ``b``: one score per scene for two clips (two models) of the same scenes; the
    differences are ``a − b`` (a scene where either is undefined is left out); without ``b``,
    ``a`` holds the per-scene differences already. Or ``sd`` instead: per scene, the score's
    standard deviation between clips of one kind; two such clips differ by √2·sd there, drawn
    as normal noise (a parametric bootstrap). ``n_scenes``: the number of scenes the mean is
    over (default: as many as given; more or fewer are resampled from the same ones). None
    with fewer than 2 usable scenes."""
    rng = np.random.default_rng(seed)
    if sd is not None:
        sds = np.asarray([s for s in sd if _ok(s)], dtype=np.float64)
        if len(sds) < 2:
            return None
        n = int(n_scenes or len(sds))
        pick = sds[rng.integers(0, len(sds), size=(resamples, n))]
        means = (math.sqrt(2.0) * pick * rng.standard_normal((resamples, n))).mean(axis=1)
    else:
        pairs = zip(a, b) if b is not None else ((x, 0.0) for x in a)
        d = np.asarray([x - y for x, y in pairs if _ok(x) and _ok(y)], dtype=np.float64)
        if len(d) < 2:
            return None
        d = d - d.mean()
        n = int(n_scenes or len(d))
        means = d[rng.integers(0, len(d), size=(resamples, n))].mean(axis=1)
    tail = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [tail, 1.0 - tail])
    return float((hi - lo) / 2.0)


def _per_variant(results: list[SceneOrder], kind: str, min_px: float,
                 get: Callable[[ClipScore], float | None]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for res in results:
        for c in res.clips:
            if c.kind == kind and c.visible(min_px) and _ok(get(c)):
                out.setdefault(c.name, {})[res.scene_id] = float(get(c))
    return out


def power_summary(results: list[SceneOrder], ns: Iterable[int] = POWER_SCENES,
                  min_px: float = MIN_PX,
                  get: Callable[[ClipScore], float | None] = lambda c: c.headline) -> dict:
    """`discriminative_power` of the headline, per kind ((i) restyles; (ii) interventions
    departing ≥ ``min_px``), for the scenes at hand and each of ``ns``: over every pair of
    variants of the kind (paired on the scenes both have, at least 3), the median and the
    largest half-width (``pairs``: how many pairs); and from the per-scene SD between the
    kind's variants (``from_sd``)."""
    out: dict[str, dict] = {}
    for kind, px in ((RIGHT, 0.0), (WRONG, min_px)):
        per = _per_variant(results, kind, px, get)
        sds = []
        for res in results:
            vals = [v[res.scene_id] for v in per.values() if res.scene_id in v]
            if len(vals) >= 2:
                sds.append(float(np.std(vals, ddof=1)))
        row: dict[str, dict] = {}
        n_here = len({s for v in per.values() for s in v})
        for n in dict.fromkeys([n_here, *ns]):
            widths = []
            for x, y in itertools.combinations(sorted(per), 2):
                common = sorted(set(per[x]) & set(per[y]))
                if len(common) >= 3:
                    w = discriminative_power([per[x][s] for s in common],
                                             [per[y][s] for s in common], n_scenes=n)
                    if w is not None:
                        widths.append(w)
            row[str(n)] = {"median": _median(widths), "max": max(widths) if widths else None,
                           "pairs": len(widths),
                           "from_sd": discriminative_power([], sd=sds, n_scenes=n)}
        out[kind] = {"scenes": n_here, "variants": sorted(per), "n_scenes": row}
    return out


# ------------------------------------------------------------------------------ summary
def study_summary(results: list[SceneOrder], metrics: list[Metric],
                  headline: Headline | None = None, meta: dict | None = None,
                  min_px: float = MIN_PX) -> dict:
    """The study's summary (``--summary``): ``meta`` (command, wall time, machine, …) and the
    goals, then per score (`score_summary`), per scene (`scene_rows`), the discriminative
    power (`power_summary`), the clips and the variants skipped."""
    headline = headline or Headline()
    skipped: dict[str, int] = {}
    for res in results:
        for name in res.skipped:
            skipped[name] = skipped.get(name, 0) + 1
    clips = {k: sum(1 for r in results for c in r.clips if c.kind == k)
             for k in dict.fromkeys(c.kind for r in results for c in r.clips)}
    clips["dose"] = sum(len(r.doses) for r in results)
    return {
        "study": "validity ordering (benchmarks/validity_study.py --order)",
        **(meta or {}),
        "n_scenes": len(results),
        "dims": {d: sum(1 for r in results if r.dim == d)
                 for d in dict.fromkeys(r.dim for r in results)},
        "scene_seconds": round(sum(r.seconds for r in results), 1),
        "goals": {"min_px": min_px, "strict_share": STRICT_SHARE, "invariance": INVARIANCE,
                  "physics_drop": DROP, "monotone_share": MONOTONE_SHARE,
                  "monotone_rho": MONOTONE_RHO},
        "headline": {"name": headline.name, "components": list(headline.components),
                     "clip": list(headline.clip), "ceiling": headline.ceiling,
                     "penalties": dict(headline.penalties)},
        "variants": {"right": sorted({c.name for r in results for c in r.clips
                                      if c.kind == RIGHT}),
                     "wrong": sorted({c.name for r in results for c in r.clips
                                      if c.kind == WRONG}),
                     "series": sorted({c.series for r in results for c in r.doses}),
                     "defined": {"right": sorted({a.name for a in APPEARANCES}),
                                 "wrong": [iv.name for iv in INTERVENTIONS]}},
        "clips": clips, "skipped": dict(sorted(skipped.items())),
        "scores": score_summary(results, metrics, headline, min_px),
        "scenes": scene_rows(results, min_px),
        "discriminative_power": power_summary(results, min_px=min_px),
    }
