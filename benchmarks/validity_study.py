"""Metric validity study (issue 9): perturbation monotonicity and the baseline ranking.

    .venv/bin/python benchmarks/validity_study.py [--n 10] [--home visphy-out] [--json out.json]

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
    from visphy_plugins.datasets.visphybench.validity import PARAMS, run_study, summarise
    from visphy_core.plugins import get_registry

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


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=10, help="scenes per parameter")
    parser.add_argument("--home", default=os.environ.get("VISPHY_HOME", "visphy-out"))
    parser.add_argument("--json", default=None)
    parser.add_argument("--skip-ranking", action="store_true")
    args = parser.parse_args()

    from visphy_plugins.datasets.visphybench.build import build_dataset

    home = Path(args.home).resolve()
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
