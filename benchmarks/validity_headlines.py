"""Which headline? Every candidate set of components scored against the validity goals, offline,
from a validity study's checkpoint ("re-weigh or replace headline components from the
study's numbers, not by taste").

    .venv/bin/python benchmarks/validity_headlines.py CHECKPOINT.jsonl
        [--pool spatiotemporal_iou,weighted_spatial_iou,track_pos_err,...] [--max-size 3]
        [--top 15] [--clip -1,1] [--ceiling twin|ideal] [--json out.json]
        [--penalties body_area_drift=0.5|none] [--weights 0,0.25,0.5,0.75,1]

The checkpoint is what ``benchmarks/validity_study.py --order --checkpoint F`` writes: every
clip of every scene scored with every frame metric, the still clip and the twin included, so a
headline of any components can be recomputed without scoring a clip again
(`visphy_plugins.studies.validity.order.rescored_headline`). For each subset of the pool (1 to
``--max-size`` components, equal weights, the headline's clip) the goals are computed as the
study computes them (`visphy_plugins.studies.validity.goals.score_summary`): strict share,
monotone share, the largest median change a restyle causes and the smallest median drop a
physics error causes. Candidates are ranked by
how many of the four goals they meet, then by the smallest margin to the goals. The pool
defaults to every metric of the checkpoint with a value on most clips (the penalties aside).

Every candidate carries the headline's penalties (``--penalties``: metric=weight, comma-separated,
or ``none``; default: the current headline's), subtracted as the headline does. ``--weights``
also prints the current components' goals with the first penalty at each of these weights: the
range where the goals hold is where the default weight comes from.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
from pathlib import Path


def load(checkpoint: Path):
    from visphy_plugins.studies.validity import clips as vc

    done = {}
    for line in checkpoint.read_text().splitlines():
        if line.strip():
            res = vc.SceneOrder.from_json(json.loads(line))
            done[res.scene_id] = res
    return list(done.values())


def evaluate(results, metrics, components: tuple[str, ...], base, ceiling: str = "twin"
             ) -> dict:
    from visphy_plugins.studies.validity import goals as vg
    from visphy_plugins.studies.validity import order as vo

    headline = dataclasses.replace(base, components=components, ceiling=ceiling)
    res = vo.rescored_headline(results, metrics, headline, ceiling)
    row = vg.score_summary(res, [], headline)["headline"]
    inv = (row.get("invariance") or {}).get("max_median")
    drop = (row.get("physics_drop") or {}).get("min_median")
    strict = (row.get("strict") or {}).get("share")
    mono = (row.get("monotone") or {}).get("share")
    margins = [
        (strict or 0) - vg.STRICT_SHARE, (mono or 0) - vg.MONOTONE_SHARE,
        (vg.INVARIANCE - inv) if inv is not None else -1.0,
        (drop - vg.DROP) if drop is not None else -1.0]
    return {"components": list(components), "strict": strict, "means":
            (row.get("means") or {}).get("share"), "monotone": mono, "invariance": inv,
            "worst_restyle": (row.get("invariance") or {}).get("worst"),
            "physics_drop": drop,
            "weakest": (row.get("physics_drop") or {}).get("weakest"),
            "goals_met": sum(m >= 0 for m in margins), "margin": min(margins)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--pool", default=None, help="comma-separated metric names")
    parser.add_argument("--max-size", type=int, default=3)
    parser.add_argument("--top", type=int, default=15)
    parser.add_argument("--clip", default="-1,1", help="the headline's clip bounds: LO,HI")
    parser.add_argument("--ceiling", choices=("twin", "ideal"), default=None,
                        help="each component's 1: the twin's value or the metric's ideal "
                        "(default: the current headline's)")
    parser.add_argument("--json", default=None)
    parser.add_argument("--penalties", default=None,
                        help="metric=weight,... subtracted from every candidate, or none "
                        "(default: the current headline's)")
    parser.add_argument("--weights", default=None,
                        help="comma-separated weights of the first penalty to sweep for the "
                        "current components")
    args = parser.parse_args(argv)

    from visphy_core.api.registry import get_registry
    from visphy_core.api.scoring import Headline

    results = load(args.checkpoint)
    if not results:
        print(f"no scenes in {args.checkpoint}", file=sys.stderr)
        return 2
    registry = get_registry()
    seen = {k for r in results for c in r.clips for k, v in c.scores.items() if v is not None}
    if args.penalties is None:
        penalties = Headline().penalties
    elif args.penalties.strip().lower() == "none":
        penalties = ()
    else:
        penalties = tuple((k.strip(), float(w)) for k, w in
                          (item.split("=", 1) for item in args.penalties.split(",") if item))
    held = {n for n, _ in penalties}
    names = args.pool.split(",") if args.pool else sorted(
        n for n in seen if n in registry.metrics and n not in held
        and all(r.twin.get(n) is not None or not r.twin for r in results[:3]))
    metrics = [registry.get("metrics", n) for n in names if n in registry.metrics]
    scorers = metrics + [registry.get("metrics", n) for n in held if n in registry.metrics]
    lo, hi = (float(v) for v in args.clip.split(","))
    args.ceiling = args.ceiling or Headline().ceiling
    base = dataclasses.replace(Headline(), clip=(lo, hi), penalties=penalties)
    rows = []
    for size in range(1, args.max_size + 1):
        for combo in itertools.combinations([m.name for m in metrics], size):
            rows.append(evaluate(results, scorers, combo, base, args.ceiling))
    rows.sort(key=lambda r: (-r["goals_met"], -r["margin"]))
    now = dataclasses.replace(Headline(), penalties=penalties)
    current = evaluate(results, scorers, tuple(c for c in now.components if c in names), now,
                       now.ceiling)
    sweep = []
    if args.weights and penalties:
        first = penalties[0][0]
        for w in (float(v) for v in args.weights.split(",")):
            h = dataclasses.replace(now, penalties=((first, w), *penalties[1:]))
            sweep.append({"weight": w, **evaluate(results, scorers, now.components, h,
                                                  now.ceiling)})

    def fmt(v, pct=False):
        return "—" if v is None else (f"{100 * v:.0f}%" if pct else f"{v:.3f}")

    print(f"{len(results)} scenes, {len(rows)} candidates; goals: strict ≥ 90%, monotone ≥ 90%, "
          "invariance ≤ 0.05, drop ≥ 0.2")
    print("| components | met | strict | means | monotone | invariance (worst) | drop "
          "(weakest) |\n|---|---|---|---|---|---|---|")
    for r in [current, *rows[:args.top]]:
        label = ", ".join(r["components"]) + (" (current)" if r is current else "")
        print(f"| {label} | {r['goals_met']}/4 | {fmt(r['strict'], True)} | "
              f"{fmt(r['means'], True)} | {fmt(r['monotone'], True)} | {fmt(r['invariance'])} "
              f"({r['worst_restyle']}) | {fmt(r['physics_drop'])} ({r['weakest']}) |")
    if sweep:
        print(f"\n{', '.join(now.components)} with {penalties[0][0]} at each weight:")
        print("| weight | met | strict | monotone | invariance (worst) | drop (weakest) |\n"
              "|---|---|---|---|---|---|")
        for r in sweep:
            print(f"| {r['weight']:g} | {r['goals_met']}/4 | {fmt(r['strict'], True)} | "
                  f"{fmt(r['monotone'], True)} | {fmt(r['invariance'])} ({r['worst_restyle']}) "
                  f"| {fmt(r['physics_drop'])} ({r['weakest']}) |")
    if args.json:
        Path(args.json).write_text(json.dumps({"scenes": len(results), "current": current,
                                               "penalties": dict(penalties),
                                               "candidates": rows, "weights": sweep},
                                              indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
