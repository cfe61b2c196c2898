"""The validity ordering's summaries (issues 21, 32): how each score orders a study's clips
(`study.run_order_study`'s `SceneOrder` results, or a checkpoint's).

Ordering (`order_of`), per scene and score, in the score's good direction (a lower-is-better
value is negated), over the clips whose value is defined:

* **means**: mean over the (i) variants > mean over the (ii) variants > max((iii), (iv));
* **strict**: every (i) variant > every (ii) variant, and every (ii) variant > both (iii) and
  (iv) (min (i) > max (ii) and min (ii) > max((iii), (iv))).

Ties are not ordered. A scene counts for a score only when at least one (i) and one (ii) value
and both (iii) and (iv) are defined. A **family** row pools its metrics: its cases are (scene,
metric) pairs and its shares are the shares of those cases (no mean value: its metrics have
different units). Also here: where each kind sits on the headline scale
(`headline_placement`), the headline recomputed under another definition from the stored
values (`rescored_headline`, `headline_alternatives`), what breaks the strict ordering
(`strict_breakers`) and the results without some variants (`without_variants`). The study's
goals (strict with the (ii) clips departing ≥ 20 px, appearance invariance, physics drop,
monotonicity in the dose, discriminative power) are summarised by `goals`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Iterable

import numpy as np

from visphy_core.api.metrics import HIGHER, Metric
from visphy_core.api.scoring import Headline, scene_headline
from visphy_plugins.studies.validity.clips import (
    FLOW,
    KINDS,
    RIGHT,
    STATIC,
    WRONG,
    ClipScore,
    SceneOrder,
)


# ----------------------------------------------------------------------------- ordering
def goodness(value: float, direction: str) -> float:
    return float(value) if direction == HIGHER else -float(value)


def order_of(right: list[float | None], wrong: list[float | None],
             baselines: list[float | None], direction: str) -> tuple[bool, bool] | None:
    """(ordered by means, ordered strictly) for one scene and score, or None when undefined
    (no (i) or (ii) value, or a baseline without one). Values in the score's own units."""
    r = [goodness(v, direction) for v in right if _ok(v)]
    w = [goodness(v, direction) for v in wrong if _ok(v)]
    if not r or not w or len(baselines) == 0 or not all(_ok(v) for v in baselines):
        return None
    b = max(goodness(v, direction) for v in baselines)
    means = bool(np.mean(r) > np.mean(w) > b)
    strict = bool(min(r) > max(w) and min(w) > b)
    return means, strict


def _ok(v: float | None) -> bool:
    return v is not None and math.isfinite(v)


def _groups(result: SceneOrder, get: Callable[[ClipScore], float | None], min_px: float = 0.0
            ) -> dict[str, list[float | None]]:
    out: dict[str, list[float | None]] = {RIGHT: [], WRONG: [], STATIC: [], FLOW: []}
    for c in result.clips:
        if c.visible(min_px):
            out[c.kind].append(get(c))
    return out


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def summarise_order(results: list[SceneOrder], metrics: list[Metric],
                    headline: Headline | None = None, min_px: float = 0.0) -> dict[str, dict]:
    """Rows ``headline`` (its name in ``name``), ``family:<family>`` and one per metric:
    ``scenes`` (cases where the ordering is defined), ``ordered_means``, ``ordered_strict``,
    their shares, and the mean value of each kind over those cases (a scene's mean over its
    variants first; None for a family). ``min_px``: only the (ii) clips whose motion departs
    from the truth's by at least that many pixels (`ClipScore.visible`); 0: every (ii) clip
    that differs from the truth at all."""
    headline = headline or Headline()
    rows: dict[str, dict] = {}

    def row(get: Callable[[ClipScore], float | None], direction: str) -> dict:
        cases, means, strict = 0, 0, 0
        kind_means: dict[str, list[float]] = {k: [] for k in KINDS}
        for res in results:
            g = _groups(res, get, min_px)
            o = order_of(g[RIGHT], g[WRONG], g[STATIC] + g[FLOW], direction)
            if o is None:
                continue
            cases += 1
            means += o[0]
            strict += o[1]
            for k in KINDS:
                vals = [v for v in g[k] if _ok(v)]
                if vals:
                    kind_means[k].append(float(np.mean(vals)))
        return {"direction": direction, "scenes": cases, "ordered_means": means,
                "ordered_strict": strict,
                "share_means": means / cases if cases else None,
                "share_strict": strict / cases if cases else None,
                **{f"mean_{k}": _mean(v) for k, v in kind_means.items()}}

    rows["headline"] = {"name": headline.name,
                        **row(lambda c: c.headline, HIGHER)}
    per_metric = {m.name: row(lambda c, n=m.name: c.scores.get(n), m.direction)
                  for m in metrics}
    for family in dict.fromkeys(m.family for m in metrics):
        members = [per_metric[m.name] for m in metrics if m.family == family]
        cases = sum(r["scenes"] for r in members)
        means = sum(r["ordered_means"] for r in members)
        strict = sum(r["ordered_strict"] for r in members)
        rows[f"family:{family}"] = {
            "metrics": [m.name for m in metrics if m.family == family], "scenes": cases,
            "ordered_means": means, "ordered_strict": strict,
            "share_means": means / cases if cases else None,
            "share_strict": strict / cases if cases else None,
            **{f"mean_{k}": None for k in KINDS}}
    rows.update(per_metric)
    return rows


def headline_placement(results: list[SceneOrder], min_px: float = 0.0) -> dict:
    """Where each kind and each variant sits on the headline scale: means over scenes, the
    static clip's exact-zero count, and the scenes where flow_extrapolate scores below every
    physics-right clip."""
    per_variant: dict[str, list[float]] = {}
    kinds: dict[str, list[float]] = {k: [] for k in KINDS}
    below, flow_cases, static_zero, static_cases = 0, 0, 0, 0
    for res in results:
        g = _groups(res, lambda c: c.headline, min_px)
        for k in KINDS:
            vals = [v for v in g[k] if _ok(v)]
            if vals:
                kinds[k].append(float(np.mean(vals)))
        for c in res.clips:
            if _ok(c.headline) and c.visible(min_px):
                per_variant.setdefault(f"{c.kind}:{c.name}", []).append(c.headline)
        right = [v for v in g[RIGHT] if _ok(v)]
        flows = [v for v in g[FLOW] if _ok(v)]
        if right and flows:
            flow_cases += 1
            below += all(f < min(right) for f in flows)
        statics = [v for v in g[STATIC] if _ok(v)]
        if statics:
            static_cases += 1
            static_zero += all(abs(v) < 1e-12 for v in statics)
    return {"kinds": {k: {"mean": _mean(v), "min": min(v) if v else None,
                          "max": max(v) if v else None, "scenes": len(v)}
                      for k, v in kinds.items()},
            "variants": {k: {"mean": _mean(v), "min": min(v), "scenes": len(v)}
                         for k, v in per_variant.items()},
            "flow_below_every_right": below, "flow_cases": flow_cases,
            "static_zero": static_zero, "static_cases": static_cases}


def rescored_headline(results: list[SceneOrder], metrics: list[Metric], headline: Headline,
                      ceiling: str = "twin") -> list[SceneOrder]:
    """``results`` with the headline recomputed under another definition (components, clip;
    ``ceiling="ideal"``: the ideal values instead of the twin's) from the stored values and
    anchors, the truth clip and the dose clips included (no clip is scored again; the static
    clip, or the scene's ``floor``, and the twin must hold every component: the study scores
    the twin with every metric)."""
    out = []
    for res in results:
        static = next((c for c in res.clips if c.kind == STATIC), None)
        held = static.scores if static is not None else res.floor
        floor = {m.name: held.get(m.name) for m in headline.metrics_of(metrics)}
        twin = res.twin if ceiling == "twin" else {}

        def again(c: ClipScore) -> ClipScore:
            return dataclasses.replace(c, headline=scene_headline(headline, metrics, c.scores,
                                                                  floor, twin)[0])

        out.append(dataclasses.replace(res, clips=[again(c) for c in res.clips],
                                       truth=again(res.truth) if res.truth else None,
                                       doses=[again(c) for c in res.doses]))
    return out


def headline_alternatives(results: list[SceneOrder], metrics: list[Metric],
                          headline: Headline | None = None, min_px: float = 0.0
                          ) -> dict[str, dict]:
    """The headline's ordering under other definitions: each component alone, each left out,
    other clip bounds, the ideal instead of the twin as the ceiling (`rescored_headline`)."""
    headline = headline or Headline()
    comps = headline.components
    variants: dict[str, tuple[Headline, str]] = {"as defined": (headline, "twin")}
    for c in comps:
        variants[f"only {c}"] = (dataclasses.replace(headline, components=(c,)), "twin")
    if len(comps) > 2:
        for c in comps:
            rest = tuple(x for x in comps if x != c)
            variants[f"without {c}"] = (dataclasses.replace(headline, components=rest), "twin")
    for clip in ((0.0, 1.0), (-1.0, 2.0), (-math.inf, math.inf)):
        variants[f"clip [{clip[0]:g}, {clip[1]:g}]"] = (dataclasses.replace(headline,
                                                                            clip=clip), "twin")
    variants["ceiling = ideal"] = (headline, "ideal")
    out = {}
    for label, (h, ceiling) in variants.items():
        res = rescored_headline(results, metrics, h, ceiling)
        out[label] = {**summarise_order(res, [], h, min_px)["headline"],
                      "placement": headline_placement(res, min_px)["kinds"]}
    return out


def strict_breakers(results: list[SceneOrder],
                    get: Callable[[ClipScore], float | None] = lambda c: c.headline,
                    direction: str = HIGHER, min_px: float = 0.0) -> dict:
    """Why the strict ordering fails, per scene where it does: ``right_low`` counts the (i)
    variant scoring lowest and ``wrong_high`` the (ii) variant scoring highest where some (ii)
    clip reaches an (i) clip; ``wrong_low`` and ``baseline_high`` the same where some (ii) clip
    does not beat both baselines (each scene counted once per failure)."""
    out: dict[str, dict[str, int]] = {"right_low": {}, "wrong_high": {}, "wrong_low": {},
                                      "baseline_high": {}}
    cases = {"right_vs_wrong": 0, "wrong_vs_baselines": 0, "scenes": 0}

    def bump(key: str, name: str) -> None:
        out[key][name] = out[key].get(name, 0) + 1

    for res in results:
        clips = [c for c in res.clips if c.visible(min_px) and _ok(get(c))]
        by = {k: [c for c in clips if c.kind == k] for k in KINDS}
        if not by[RIGHT] or not by[WRONG] or not by[STATIC] or not by[FLOW]:
            continue
        cases["scenes"] += 1

        def g(c: ClipScore) -> float:
            return goodness(get(c), direction)

        low_r, high_w = min(by[RIGHT], key=g), max(by[WRONG], key=g)
        low_w = min(by[WRONG], key=g)
        high_b = max(by[STATIC] + by[FLOW], key=g)
        if not g(low_r) > g(high_w):
            cases["right_vs_wrong"] += 1
            bump("right_low", low_r.name)
            bump("wrong_high", high_w.name)
        if not g(low_w) > g(high_b):
            cases["wrong_vs_baselines"] += 1
            bump("wrong_low", low_w.name)
            bump("baseline_high", high_b.name)
    return {**cases, **{k: dict(sorted(v.items(), key=lambda kv: -kv[1]))
                        for k, v in out.items()}}


def without_variants(results: list[SceneOrder], names: Iterable[str]) -> list[SceneOrder]:
    """``results`` without the clips of the named variants (e.g. to see what breaks an
    ordering); composes with every summary here."""
    drop = set(names)
    return [dataclasses.replace(r, clips=[c for c in r.clips if c.name not in drop])
            for r in results]
