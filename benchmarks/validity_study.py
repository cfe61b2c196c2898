"""Metric validity study (issues 9, 21): perturbation monotonicity, the baseline ranking and the
validity ordering.

    .venv/bin/python benchmarks/validity_study.py [--n 10] [--home visphy-out] [--json out.json]
    .venv/bin/python benchmarks/validity_study.py --order [--every N] [--dims 2d,3d]
        [--checkpoint scenes.jsonl] [--json out.json]

1. Perturbation: for each parameter (restitution, friction, initial speed, gravity), the first
   ``n`` non-chaotic 2D scenes of the generated benchmark that reveal it (its
   ``ground_truth.identifiable``); the parameter is pushed from the truth in 5 growing steps,
   re-simulated (Box2D) and rendered like the ground truth; every pixel, motion
   and object-track metric scores the result (visphy's unaligned pairing). Per metric: the cases,
   how many have Spearman ρ(step, worsening) ≥ 0.9, the mean ρ, and the pooled ρ (the step
   against the mean worsening over the cases) over all cases and per parameter
   (`visphy_plugins.datasets.visphybench.validity`).
2. Ranking: ten 2D scenes of the ``test`` split run through the real CLI with the default
   (offline) suite for the oracle and the two pixel-space baselines (`static`: the first key
   frame held; `flow_extrapolate`: DIS flow between the key frames extrapolated) — the means.
Prints both tables as Markdown (the README's).

``--order`` runs the validity ordering instead (issue 21,
`visphy_plugins.datasets.visphybench.validity_order`): every scene of the ``test`` split (every
``N``-th with ``--every N``; 2D in-process, 3D through Chromium), four kinds of clip —
(i) the physics of the truth drawn differently, (ii) the physics changed and re-simulated,
(iii) the static baseline, (iv) the flow_extrapolate baseline — scored by the default offline
suite's frame and sequence metrics (visphy's unaligned pairing) and by the headline
(``physics_score``: floor = the static clip, ceiling = the twin). Per score: the scenes where
mean (i) > mean (ii) > max((iii), (iv)) ("means") and where every (i) > every (ii) > both
baselines ("strict"), and the mean value of each kind; then where each kind sits on the
headline scale, how the headline's shares move when only clearly wrong (ii) clips count, and
under other headline definitions. ``--checkpoint``: each scored scene is appended there and a
rerun skips the scenes it holds.
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
    from visphy_plugins.datasets.visphybench.validity import PARAMS, run_study, summarise

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
    from visphy_plugins.datasets.visphybench.validity_order import frame_metrics

    names = yaml.safe_load((REPO / "conf" / "metrics" / "default.yaml").read_text())["names"]
    registry = get_registry()
    return frame_metrics(registry.get("metrics", n) for n in names)


#: (ii) clips count only when their motion departs from the truth's by at least this many px
#: (the headline's sensitivity table; 0: every (ii) clip that differs at all, the main table)
VISIBLE_STEPS = (0.0, 2.0, 5.0, 20.0, 50.0)
#: the (i) variants that change the silhouette (the ones a motion mask sees)
RESIZED = ("grow", "shrink")


def order_study(catalogue: dict, every: int, dims: tuple[str, ...], checkpoint: str | None,
                progress: bool) -> dict:
    from visphy_plugins.datasets.visphybench import validity_order as vo

    by_id = {s["spec"]["scene_id"]: s["spec"] for s in catalogue["scenes"]}
    specs = [by_id[i] for i in catalogue["splits"]["test"] if by_id[i]["dim"] in dims]
    specs = specs[::max(1, every)]
    metrics = default_suite()
    done: dict = {}
    if checkpoint and Path(checkpoint).is_file():
        for line in Path(checkpoint).read_text().splitlines():
            if line.strip():
                res = vo.SceneOrder.from_json(json.loads(line))
                done[res.scene_id] = res

    t0 = time.perf_counter()
    fresh = []

    def save(res) -> None:  # the checkpoint writer; counts the scenes this run scores
        fresh.append(res.scene_id)
        if checkpoint:
            with open(checkpoint, "a") as fh:
                fh.write(json.dumps(res.to_json()) + "\n")

    results = vo.run_order_study(
        specs, metrics, dims=dims, done=done, on_scene=save,
        progress=(lambda s: print(f"  {s}", file=sys.stderr, flush=True)) if progress else None)
    wall = time.perf_counter() - t0
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
            into = unchanged if why.endswith("the clip equals the truth") else skipped
            into[name] = into.get(name, 0) + 1
    counts = {k: sum(1 for r in results for c in r.clips if c.kind == k) for k in vo.KINDS}
    scene_s = {d: [r.seconds for r in results if r.dim == d] for d in dims}

    n2 = sum(1 for r in results if r.dim == "2d")
    print(f"### Validity ordering ({len(results)} scenes of the test split: {n2} 2D, "
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
              + " | ".join(_fmt(row[f"mean_{k}"]) for k in vo.KINDS) + " |")
    kinds = placement["kinds"]
    print("\n### The headline scale (physics_score: 0 = the static clip, 1 = the twin)\n")
    print("| clip | mean | min | max | scenes |")
    print("|---|---|---|---|---|")
    for k, label in vo.KINDS.items():
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
              + " | ".join(_fmt(row[f"mean_{k}"]) for k in vo.KINDS)
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
        print("\n(ii) variants skipped because their clip equals the truth (scenes): "
              + ", ".join(f"{k} {v}" for k, v in sorted(unchanged.items())))
    if skipped:
        print("\n(ii) variants that do not apply (scenes; speed and mirror need a thrown body, "
              "kick one at rest) or failed: "
              + ", ".join(f"{k} {v}" for k, v in sorted(skipped.items())))
    return {"scenes": [r.scene_id for r in results], "wall_s": round(wall, 1),
            "scene_seconds": {d: round(sum(v), 1) for d, v in scene_s.items()},
            "table": table, "placement": placement,
            "sensitivity": {str(k): v for k, v in sensitivity.items()},
            "alternatives": alternatives, "skipped": skipped, "unchanged": unchanged,
            "strict_breakers": breakers, "scored_this_run": fresh,
            "results": [r.to_json() for r in results]}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=10, help="scenes per parameter")
    parser.add_argument("--home", default=os.environ.get("VISPHY_HOME", "visphy-out"))
    parser.add_argument("--json", default=None)
    parser.add_argument("--skip-ranking", action="store_true")
    parser.add_argument("--order", action="store_true",
                        help="the validity ordering (issue 21) instead of the other studies")
    parser.add_argument("--every", type=int, default=1,
                        help="--order: every N-th scene of the test split")
    parser.add_argument("--dims", default="2d,3d", help="--order: 2d, 3d or 2d,3d")
    parser.add_argument("--checkpoint", default=None,
                        help="--order: append each scored scene here; skip those it holds")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    args = parser.parse_args()

    from visphy_plugins.datasets.visphybench.build import build_dataset

    home = Path(args.home).resolve()
    t_build = time.perf_counter()
    root = build_dataset(home / "data", split="test", progress=False)
    catalogue = json.loads((root / "catalogue.json").read_text())
    if args.order:
        dims = tuple(d.strip() for d in args.dims.split(",") if d.strip())
        print(f"(test split ready in {time.perf_counter() - t_build:.0f} s)\n",
              file=sys.stderr)
        result = order_study(catalogue, args.every, dims, args.checkpoint, not args.quiet)
        if args.json:
            Path(args.json).write_text(json.dumps(result, indent=1))
        return
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
