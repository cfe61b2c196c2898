"""Metric validity study (issues 9, 21, 32): perturbation monotonicity, the baseline ranking and the
validity ordering.

    .venv/bin/python benchmarks/validity_study.py [--n 10] [--home visphy-out] [--json out.json]
    .venv/bin/python benchmarks/validity_study.py --order [--split test] [--every N]
        [--dims 2d,3d] [--checkpoint scenes.jsonl] [--json out.json]
        [--summary visphy_core/api/validity_summary.json] [--dose | --no-dose]
        [--variants NAMES] [--metrics NAMES] [--clips-cache DIR]

1. Perturbation: for each parameter (restitution, friction, initial speed, gravity), the first
   ``n`` non-chaotic 2D scenes of the generated benchmark that reveal it (its
   ``ground_truth.identifiable``); the parameter is pushed from the truth in 5 growing steps,
   re-simulated (Box2D) and rendered like the ground truth; every pixel, motion
   and object-track metric scores the result (visphy's unaligned pairing). Per metric: the cases,
   how many have Spearman ρ(step, worsening) ≥ 0.9, the mean ρ, and the pooled ρ (the step
   against the mean worsening over the cases) over all cases and per parameter
   (`visphy_plugins.studies.validity.perturbation`).
2. Ranking: ten 2D scenes of the ``test`` split run through the real CLI with the default
   (offline) suite for the oracle and the two pixel-space baselines (`static`: the first key
   frame held; `flow_extrapolate`: DIS flow between the key frames extrapolated) — the means.
Prints both tables as Markdown (the README's).

``--order`` runs the validity ordering instead
(`visphy_plugins.studies.validity.study`, `.order`): every scene of the ``test`` split (every
``N``-th with ``--every N``; 2D in-process, 3D through Chromium), four kinds of clip —
(i) the physics of the truth drawn differently, (ii) the physics changed and re-simulated,
(iii) the static baseline, (iv) the flow_extrapolate baseline — scored by the default offline
suite's frame and sequence metrics (visphy's unaligned pairing) and by the headline
(``physics_score``: floor = the static clip, ceiling = the twin). Per score: the scenes where
mean (i) > mean (ii) > max((iii), (iv)) ("means") and where every (i) > every (ii) > both
baselines ("strict"), and the mean value of each kind; then where each kind sits on the
headline scale, how the headline's shares move when only clearly wrong (ii) clips count, and
under other headline definitions. ``--checkpoint``: each scored scene is appended there and a
rerun skips the scenes it holds (those scored with the same metrics, variants and series; the
last line of a scene wins).

The extended study adds restyles (colour ±40 %, swapped colours, line widths, background shade), the
truth clip itself as the reference, the twin scored with every metric, and the dose series
(`visphy_plugins.studies.validity.dose`: gravity ×0.9/×0.75/×0.5, restitution −0.1/−0.2/−0.3, launch
+5°/+10°/+20°, playback ×0.9/×0.8/×0.67), and prints, per score, the goals
(`visphy_plugins.studies.validity.goals`): strict ordering with the (ii) clips departing ≥ 20 px,
appearance invariance (median |Δ| per restyle), physics drop (median per intervention ≥ 20 px),
monotone share over the dose series; a table per scene; the discriminative power.
``--summary`` (default ``visphy_core/api/validity_summary.json``: the figures the metric
registry, the docs' generated pages and the tests read; ``''`` for none) writes all of it as
JSON with the scenes, wall time, machine (``benchmarks/machine.py``) and command line.
``--no-dose`` leaves the dose series out; ``--variants`` keeps only the named (i) and (ii)
variants and dose series (``right``, ``wrong``, ``dose``: a whole group); ``--metrics`` only
these metrics of the default suite; ``--split`` another split (``mini``: four 2D scenes);
``--clips-cache DIR`` keeps the rendered clips (npz) so a rerun with other metrics skips
simulating and drawing them. ``--order`` reads only the catalogue (it draws its own clips).

The whole study (49 scenes of the test split, 44 2D and 5 3D)::

    .venv/bin/python benchmarks/validity_study.py --order --checkpoint validity.jsonl \
        --json validity.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FAMILIES = ("pixel", "motion", "physics")
RANK_COLUMNS = ("psnr", "ssim", "st_lpips", "flow_epe_dis", "flow_epe_moving_dis",
                "track_pos_err", "track_vel_err", "event_contact_err")


def _fmt(v, decimals: int | None = None) -> str:
    if v is None:
        return "—"
    return f"{v:.3g}" if decimals is None else f"{v:.{decimals}f}".replace("-", "−")


def perturbation(specs: list[dict], per_param: int, progress: bool) -> tuple[dict, list]:
    from visphy_core.api.registry import get_registry
    from visphy_plugins.studies.validity.perturbation import PARAMS, run_study, summarise

    registry = get_registry()
    metrics = [registry.get("metrics", n) for n in sorted(registry.metrics)]
    metrics = [m for m in metrics if m.family in FAMILIES and m.kind != "scene"
               and m.unavailable_reason() is None and not m.name.startswith("raft")]
    cases = run_study(specs, metrics, per_param=per_param,
                      progress=(lambda s: print(f"  {s}", file=sys.stderr)) if progress else None)
    directions = {m.name: m.direction for m in metrics}
    table = {"all": summarise(cases, directions)}
    for p in PARAMS:
        table[p] = summarise(cases, directions, param=p)
    return table, cases


def ranking(scene_ids: list[str], home: Path) -> dict[str, dict]:
    out = {}
    for model in ("oracle", "static", "flow_extrapolate"):
        cmd = [sys.executable, "-m", "visphy_core", f"model={model}", "dataset=visphybench_test",
               f"dataset.scenes=[{','.join(scene_ids)}]", "tracking=none", "run.progress=false",
               "metrics.spec_track=false"]
        proc = subprocess.run(cmd, cwd=REPO, env=dict(os.environ, VISPHY_HOME=str(home)),
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"{model}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
        run_dir = max((home / "runs").iterdir(), key=lambda p: p.stat().st_mtime)
        summary = json.loads((run_dir / "summary.json").read_text())
        out[model] = {c: summary["metrics"].get(c, {}).get("mean_with_fallbacks")
                      for c in RANK_COLUMNS}
    return out


def _share(n: int, d: int) -> str:
    return f"{n}/{d} ({n / d:.0%})" if d else "—"


def default_suite() -> list:
    """The default offline suite (conf/metrics/default.yaml), its frame and sequence metrics
    that run here."""
    import yaml

    from visphy_core.api.registry import get_registry
    from visphy_plugins.studies.validity.study import frame_metrics

    names = yaml.safe_load((REPO / "conf" / "metrics" / "default.yaml").read_text())["names"]
    registry = get_registry()
    return frame_metrics(registry.get("metrics", n) for n in names)


#: (ii) clips count only when their motion departs from the truth's by at least this many px
#: (the headline's sensitivity table; 0: every (ii) clip that differs at all, the main table)
VISIBLE_STEPS = (0.0, 2.0, 5.0, 20.0, 50.0)
#: the (i) variants that change the silhouette (the ones a motion mask sees)
RESIZED = ("grow", "shrink")


#: where ``--order`` writes its summary (the docs and tests read it)
SUMMARY = REPO / "visphy_core" / "api" / "validity_summary.json"


def split_specs(catalogue, split: str, dims: tuple[str, ...], every: int) -> list[dict]:
    """Every ``every``-th scene of ``split`` in ``dims`` (a `Catalogue`'s specs, split order)."""
    by_id = {e.spec["scene_id"]: e.spec for e in catalogue.entries}
    specs = [by_id[i] for i in catalogue.splits[split] if by_id[i]["dim"] in dims]
    return specs[::max(1, every)]


def order_study(specs: list[dict], dims: tuple[str, ...], checkpoint: str | None,
                progress: bool, *, metrics: list | None = None, dose: bool = True,
                variants: list[str] | None = None, clips_cache: str | None = None,
                summary: str | Path | None = None, meta: dict | None = None) -> dict:
    """The validity ordering on ``specs`` (in ``dims``) with ``metrics`` (default: the default
    suite's frame and sequence metrics); prints its tables and, with ``summary``, writes the
    goals' summary there (`goals.study_summary`, ``meta`` included)."""
    from visphy_plugins.studies.validity import clips as vc
    from visphy_plugins.studies.validity import goals as vg
    from visphy_plugins.studies.validity import order as vo
    from visphy_plugins.studies.validity import study as vs

    metrics = default_suite() if metrics is None else metrics
    appearances = interventions = series = None
    if variants:
        appearances, interventions, series = vs.variants_named(variants)
    done: dict = {}
    if checkpoint and Path(checkpoint).is_file():
        for line in Path(checkpoint).read_text().splitlines():
            if line.strip():
                res = vc.SceneOrder.from_json(json.loads(line))
                done[res.scene_id] = res  # the last line of a scene wins

    t0 = time.perf_counter()
    fresh = []

    def save(res) -> None:  # the checkpoint writer; counts the scenes this run scores
        fresh.append(res.scene_id)
        if checkpoint:
            with open(checkpoint, "a") as fh:
                fh.write(json.dumps(res.to_json()) + "\n")

    results = vs.run_order_study(
        specs, metrics, dims=dims, done=done, on_scene=save,
        progress=(lambda s: print(f"  {s}", file=sys.stderr, flush=True)) if progress else None,
        appearances=appearances, interventions=interventions, dose=dose, series=series,
        clips_cache=vc.ClipCache(clips_cache) if clips_cache else None)
    wall = time.perf_counter() - t0
    # the headline as it is defined now, from the stored values (a checkpoint's scenes may
    # have been scored under another definition; no clip is scored again)
    from visphy_core.api.scoring import Headline

    results = vo.rescored_headline(results, metrics, Headline())
    table = vo.summarise_order(results, metrics)
    placement = vo.headline_placement(results)
    same_size = vo.without_variants(results, RESIZED)
    sensitivity = {px: {**vo.summarise_order(results, [], min_px=px)["headline"],
                        "same_size": vo.summarise_order(same_size, [], min_px=px)["headline"]}
                   for px in VISIBLE_STEPS}
    alternatives = vo.headline_alternatives(results, metrics)
    for label, row in vo.headline_alternatives(same_size, metrics).items():
        alternatives[label]["same_size"] = {k: v for k, v in row.items() if k != "placement"}
    breakers = vo.strict_breakers(results)
    skipped: dict[str, int] = {}
    unchanged: dict[str, int] = {}
    for res in results:
        for name, why in res.skipped.items():
            into = unchanged if why.endswith(("the clip equals the truth",
                                              "the clip equals the previous dose's")) \
                else skipped
            into[name] = into.get(name, 0) + 1
    counts = {k: sum(1 for r in results for c in r.clips if c.kind == k) for k in vc.KINDS}
    scene_s = {d: [r.seconds for r in results if r.dim == d] for d in dims}

    n2 = sum(1 for r in results if r.dim == "2d")
    split = (meta or {}).get("split", "test")
    print(f"### Validity ordering ({len(results)} scenes of the {split} split: {n2} 2D, "
          f"{len(results) - n2} 3D; clips (i) {counts['right']}, (ii) {counts['wrong']}, "
          f"(iii) {counts['static']}, (iv) {counts['flow']}; "
          + ", ".join(f"{d} {sum(v):.0f} s ({sum(v) / len(v):.0f} s a scene)"
                      for d, v in scene_s.items() if v)
          + f"; this run scored {len(fresh)} of them in {wall:.0f} s)\n")
    print("Ordered: in the score's good direction, *means* = mean over (i) > mean over (ii) > "
          "max((iii), (iv)); *strict* = every (i) > every (ii) > both (iii) and (iv). A family "
          "pools its metrics' (scene, metric) cases.\n")
    print("| score | ↑↓ | scenes | ordered (means) | ordered (strict) | (i) right | (ii) wrong "
          "| (iii) static | (iv) flow |")
    print("|---|---|---|---|---|---|---|---|---|")
    for key, row in table.items():
        if key == "headline":
            label = f"**headline `{row['name']}`**"
        elif key.startswith("family:"):
            label = f"family *{key.split(':', 1)[1]}*"
        else:
            label = f"`{key}`"
        arrow = {"higher": "↑", "lower": "↓"}.get(row.get("direction"), "")
        print(f"| {label} | {arrow} | {row['scenes']} | "
              f"{_share(row['ordered_means'], row['scenes'])} | "
              f"{_share(row['ordered_strict'], row['scenes'])} | "
              + " | ".join(_fmt(row[f"mean_{k}"]) for k in vc.KINDS) + " |")
    kinds = placement["kinds"]
    print("\n### The headline scale (physics_score: 0 = the static clip, 1 = the twin)\n")
    print("| clip | mean | min | max | scenes |")
    print("|---|---|---|---|---|")
    for k, label in vc.KINDS.items():
        r = kinds[k]
        print(f"| {label} (scene mean) | {_fmt(r['mean'])} | {_fmt(r['min'])} | "
              f"{_fmt(r['max'])} | {r['scenes']} |")
    for name, r in placement["variants"].items():
        print(f"| {name} | {_fmt(r['mean'])} | {_fmt(r['min'])} | | {r['scenes']} |")
    print(f"\nflow_extrapolate below every physics-right clip: "
          f"{_share(placement['flow_below_every_right'], placement['flow_cases'])} scenes; "
          f"static exactly 0: {_share(placement['static_zero'], placement['static_cases'])}.")
    print("\n### Headline ordering when only clearly wrong (ii) clips count\n")
    print("Last column: the strict ordering without the resized (i) variants (grow, shrink).\n")
    print("| (ii) motion departs by ≥ | scenes | ordered (means) | ordered (strict) "
          "| (ii) mean | strict without grow/shrink |")
    print("|---|---|---|---|---|---|")
    for px, row in sensitivity.items():
        same = row["same_size"]
        print(f"| {px:g} px | {row['scenes']} | {_share(row['ordered_means'], row['scenes'])} | "
              f"{_share(row['ordered_strict'], row['scenes'])} | {_fmt(row['mean_wrong'])} | "
              f"{_share(same['ordered_strict'], same['scenes'])} |")
    print("\n### Other headline definitions (same clips, recomputed)\n")
    print("| headline | scenes | ordered (means) | ordered (strict) | (i) | (ii) | (iii) | (iv) "
          "| strict without grow/shrink |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, row in alternatives.items():
        same = row["same_size"]
        print(f"| {label} | {row['scenes']} | {_share(row['ordered_means'], row['scenes'])} | "
              f"{_share(row['ordered_strict'], row['scenes'])} | "
              + " | ".join(_fmt(row[f"mean_{k}"]) for k in vc.KINDS)
              + f" | {_share(same['ordered_strict'], same['scenes'])} |")
    print(f"\nWhere the headline's strict ordering fails ({breakers['scenes']} scenes): some "
          f"(ii) clip reaches an (i) clip on {breakers['right_vs_wrong']} (lowest (i): "
          + ", ".join(f"{k} {v}" for k, v in breakers["right_low"].items())
          + "; highest (ii): " + ", ".join(f"{k} {v}" for k, v in breakers["wrong_high"].items())
          + f"); some (ii) clip does not beat both baselines on {breakers['wrong_vs_baselines']}"
          + " (lowest (ii): " + ", ".join(f"{k} {v}" for k, v in breakers["wrong_low"].items())
          + "; best baseline: "
          + ", ".join(f"{k} {v}" for k, v in breakers["baseline_high"].items()) + ").")
    if unchanged:
        print("\nVariants skipped because their clip equals the truth or the previous dose's "
              "(scenes): "
              + ", ".join(f"{k} {v}" for k, v in sorted(unchanged.items())))
    if skipped:
        print("\nVariants that do not apply (scenes; speed, mirror and the launch series need a "
              "thrown body, kick one at rest; swapped two body colours) or failed: "
              + ", ".join(f"{k} {v}" for k, v in sorted(skipped.items())))
    goals = vg.study_summary(results, metrics, meta={
        **(meta or {}), "wall_s": round(wall, 1), "scored_this_run": len(fresh),
        "scene_ids": [r.scene_id for r in results]})
    print_goals(goals)
    if summary:
        Path(summary).parent.mkdir(parents=True, exist_ok=True)
        Path(summary).write_text(json.dumps(goals, indent=1) + "\n")
        print(f"\n(summary written to {summary})", file=sys.stderr)
    return {"scenes": [r.scene_id for r in results], "wall_s": round(wall, 1),
            "scene_seconds": {d: round(sum(v), 1) for d, v in scene_s.items()},
            "table": table, "placement": placement,
            "sensitivity": {str(k): v for k, v in sensitivity.items()},
            "alternatives": alternatives, "skipped": skipped, "unchanged": unchanged,
            "strict_breakers": breakers, "scored_this_run": fresh, "goals": goals,
            "results": [r.to_json() for r in results]}


def _yes(v) -> str:
    return "—" if v is None else ("yes" if v else "no")


def print_goals(goals: dict) -> None:
    """The goal tables: per score, per dose series (headline), per scene, and the
    discriminative power."""
    g = goals["goals"]
    print(f"\n### Goals: strict on ≥ {g['strict_share']:.0%} of scenes ((ii) clips "
          f"departing ≥ {g['min_px']:g} px), each restyle ≤ {g['invariance']:g} and each "
          f"intervention ≥ {g['physics_drop']:g} (medians, the headline's scale), monotone in "
          f"the dose (ρ ≤ {g['monotone_rho']:g}) on ≥ {g['monotone_share']:.0%}\n")
    print("| score | strict | means | monotone (cases) | monotone (scenes) | worst restyle "
          "(median \\|Δ\\|) | weakest intervention (median drop) |")
    print("|---|---|---|---|---|---|---|")
    for key, row in goals["scores"].items():
        label = f"**{row['name']}**" if key == "headline" else f"`{key}`"
        inv, drop, mono = row["invariance"], row["physics_drop"], row["monotone"]
        print(f"| {label} | {_share(row['strict']['ordered'], row['strict']['scenes'])} | "
              f"{_share(row['means']['ordered'], row['means']['scenes'])} | "
              f"{_share(mono['monotone'], mono['cases'])} | "
              f"{_share(mono['scenes_monotone'], mono['scenes'])} | "
              f"{inv['worst'] or '—'} {_fmt(inv['max_median'])} | "
              f"{drop['weakest'] or '—'} {_fmt(drop['min_median'])} |")
    head = goals["scores"]["headline"]
    print("\nHeadline per dose series: " + "; ".join(
        f"{name} {_share(r['monotone'], r['cases'])} (mean ρ {_fmt(r['mean_rho'], 2)})"
        for name, r in head["monotone"]["per_series"].items()) + ".")
    print("Headline per restyle (median |Δ|): " + ", ".join(
        f"{n} {_fmt(r['median_abs'])}" for n, r in head["invariance"]["per_restyle"].items())
          + ".")
    print("Headline per intervention ≥ 20 px (median drop): " + ", ".join(
        f"{n} {_fmt(r['median'])} ({r['scenes']})"
        for n, r in head["physics_drop"]["per_intervention"].items()) + ".")
    print("\n| scene | dim | strict | means | monotone | worst restyle | smallest ≥ 20 px drop |")
    print("|---|---|---|---|---|---|---|")
    for r in goals["scenes"]:
        print(f"| {r['scene']} | {r['dim']} | {_yes(r['strict'])} | {_yes(r['means'])} | "
              f"{_fmt(r['monotone'], 2)} | {_fmt(r['worst_restyle'])} "
              f"({r['worst_restyle_name'] or '—'}) | {_fmt(r['smallest_drop'])} "
              f"({r['smallest_drop_name'] or '—'}) |")
    print("\nDiscriminative power (headline; the half-width of a 95 % paired-bootstrap interval "
          "of a mean difference between two variants of one kind, median over pairs / from "
          "the per-scene SD):")
    for kind, row in goals["discriminative_power"].items():
        print(f"  {kind}: " + "; ".join(
            f"n={n} {_fmt(r['median'])} / {_fmt(r['from_sd'])}"
            for n, r in row["n_scenes"].items()))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=10, help="scenes per parameter")
    parser.add_argument("--home", default=os.environ.get("VISPHY_HOME", "visphy-out"))
    parser.add_argument("--json", default=None)
    parser.add_argument("--skip-ranking", action="store_true")
    parser.add_argument("--order", action="store_true",
                        help="the validity ordering instead of the other studies")
    parser.add_argument("--every", type=int, default=1,
                        help="--order: every N-th scene of the test split")
    parser.add_argument("--dims", default="2d,3d", help="--order: 2d, 3d or 2d,3d")
    parser.add_argument("--checkpoint", default=None,
                        help="--order: append each scored scene here; skip those it holds")
    parser.add_argument("--split", default="test", help="--order: the split (test, sub, mini)")
    parser.add_argument("--dose", action=argparse.BooleanOptionalAction, default=True,
                        help="--order: the dose series (default on)")
    parser.add_argument("--variants", default=None,
                        help="--order: only these (i), (ii) variants and dose series, "
                             "comma-separated (right, wrong, dose: a whole group)")
    parser.add_argument("--metrics", default=None,
                        help="--order: only these metrics of the default suite, comma-separated")
    parser.add_argument("--clips-cache", default=None,
                        help="--order: keep the rendered clips here (npz) and reuse them")
    parser.add_argument("--summary", default=str(SUMMARY),
                        help="--order: write the goals' summary (JSON) here; '' for none")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    args = parser.parse_args()

    from visphy_plugins.datasets.visphybench.build import build_dataset

    home = Path(args.home).resolve()
    if args.order:  # the study draws its own clips: the catalogue is all it reads
        from machine import machine

        from visphy_plugins.datasets.visphybench.build import (
            dataset_root,
            load_or_build_catalogue,
        )

        root = dataset_root(home / "data")
        root.mkdir(parents=True, exist_ok=True)
        catalogue = load_or_build_catalogue(root, 0, progress=False)
        dims = tuple(d.strip() for d in args.dims.split(",") if d.strip())
        specs = split_specs(catalogue, args.split, dims, args.every)
        metrics = None
        if args.metrics:
            wanted = [n.strip() for n in args.metrics.split(",") if n.strip()]
            suite = {m.name: m for m in default_suite()}
            unknown = [n for n in wanted if n not in suite]
            if unknown:
                raise SystemExit(f"--metrics: not in the default suite here: {unknown}")
            metrics = [suite[n] for n in wanted]
        meta = {"command": " ".join([Path(sys.executable).name, *sys.argv]),
                "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "split": args.split,
                "every": args.every, "dims_asked": list(dims), "dose": args.dose,
                "variants_asked": args.variants, "machine": machine()}
        result = order_study(specs, dims, args.checkpoint, not args.quiet, metrics=metrics,
                             dose=args.dose,
                             variants=args.variants.split(",") if args.variants else None,
                             clips_cache=args.clips_cache, summary=args.summary or None,
                             meta=meta)
        if args.json:
            Path(args.json).write_text(json.dumps(result, indent=1))
        return
    root = build_dataset(home / "data", split="test", progress=False)
    catalogue = json.loads((root / "catalogue.json").read_text())
    specs = [s["spec"] for s in catalogue["scenes"] if s["spec"]["dim"] == "2d"]
    t0 = time.perf_counter()
    table, cases = perturbation(specs, args.n, progress=True)
    study_s = time.perf_counter() - t0
    n_scenes = len({c.scene_id for c in cases})
    counts = {p: len([c for c in cases if c.param == p]) for p in table if p != "all"}
    print(f"### Perturbation monotonicity ({n_scenes} 2D scenes; cases per parameter: "
          + ", ".join(f"{p} {n}" for p, n in counts.items())
          + f"; 5 steps each; {study_s:.0f} s)\n")
    print("| metric | cases | ρ ≥ 0.9 | mean ρ | pooled ρ: all / e / μ / v0 / g |")
    print("|---|---|---|---|---|")
    for name, r in table["all"].items():
        pooled = " / ".join(_fmt(table[p][name]["pooled_rho"], 2) for p in ("all", *counts))
        print(f"| `{name}` | {r['cases']} | {r['passed']} | {_fmt(r['mean_rho'], 2)} | "
              f"{pooled} |")
    test_ids = set(catalogue["splits"]["test"])
    ranked = [s["scene_id"] for s in specs if s["scene_id"] in test_ids][:10]
    result = {"scenes": sorted({c.scene_id for c in cases}), "perturbation": table,
              "study_s": round(study_s, 1), "ranking_scenes": ranked}
    if not args.skip_ranking:
        ranks = ranking(ranked, home)
        print(f"\n### Baselines on {len(ranked)} 2D scenes of the test split (means)\n")
        print("| model | " + " | ".join(f"`{c}`" for c in RANK_COLUMNS) + " |")
        print("|---" * (len(RANK_COLUMNS) + 1) + "|")
        for model, row in ranks.items():
            print(f"| {model} | " + " | ".join(_fmt(row[c]) for c in RANK_COLUMNS) + " |")
        result["ranking"] = ranks
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
