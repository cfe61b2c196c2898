"""Scaling of a whole run: wall time over 50, 100 and 209 scenes, and from 1 to 2 workers.

    .venv/bin/python benchmarks/bench_scaling.py [--counts 50,100,209] [--workers 1,2]
        [--workers-at 50] [--dataset visphybench] [--model oracle] [--engine threejs]
        [--metrics default | --metric-names psnr,ssim] [--home visphy-out] [--json out.json]

Each subset is evenly spaced over the split (so it keeps the split's 2D/3D mix: the generated
benchmark lists its 2D scenes first), and each run starts from an empty cache
(`bench_run.run_once`). The scene counts run with the most workers of ``--workers``; the worker
counts run on ``--workers-at`` scenes. Prints one table (scenes, workers, wall, CPU seconds,
per scene, peak RSS of the process tree, load average) and the two ratios the goal names:
wall per scene across counts (linear: about 1) and the speed-up from the fewest to the most
workers. On a shared machine wall figures are upper bounds, and a speed-up needs the cores to
be free: with Linux's autogroup scheduling every process of one session shares one CPU share,
so where other sessions keep the cores busy more workers add no CPU time; CPU seconds per scene
still compare.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_run import run_once, split_ids  # noqa: E402
from machine import machine_info  # noqa: E402


def evenly(ids: list[str], n: int) -> list[str]:
    """``n`` ids spread evenly over ``ids`` (first and last included), in their order."""
    if n >= len(ids):
        return list(ids)
    step = (len(ids) - 1) / max(1, n - 1)
    return [ids[round(i * step)] for i in range(n)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--counts", default="50,100,209")
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--workers-at", type=int, default=50)
    parser.add_argument("--dataset", default="visphybench")
    parser.add_argument("--model", default="oracle")
    parser.add_argument("--engine", default="threejs")
    parser.add_argument("--metrics", default="default")
    parser.add_argument("--metric-names")
    parser.add_argument("--home", default=os.environ.get("VISPHY_HOME", "visphy-out"))
    parser.add_argument("--json")
    args = parser.parse_args()
    home = Path(args.home).resolve()
    ids = split_ids(args.dataset, home)
    counts = [int(c) for c in args.counts.split(",")]
    workers = [w.strip() for w in args.workers.split(",")]
    plan = [(n, workers[-1]) for n in counts] + [(args.workers_at, w) for w in workers[:-1]]
    info = machine_info()
    rows = []
    for n, w in plan:
        figures = run_once(dataset=args.dataset, scene_ids=evenly(ids, n), limit=None,
                           model=args.model, engine=args.engine,
                           metrics=None if args.metric_names else args.metrics,
                           metric_names=args.metric_names, workers=w, home=home,
                           warm_cache=False)
        rows.append(figures)
        print(f"… {figures['scenes']} scenes, {figures['workers']['workers']} worker(s): "
              f"{figures['wall_s']} s wall, {figures['cpu_s']} s CPU", flush=True)
    print(f"\nmachine: {info['usable_cores']} usable cores · {info['cpu']} · "
          f"{info['memory_gib']} GiB · model {args.model} × {args.engine} · metrics "
          f"{args.metric_names or args.metrics}")
    print("| scenes (3D) | workers | wall s | CPU s | wall s/scene | CPU s/scene | peak RSS GiB"
          " | load avg start → end |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scenes']} ({r['scenes_3d']}) | {r['workers']['workers']} | {r['wall_s']} "
              f"| {r['cpu_s']} | {r['wall_s_per_scene']} | {r['cpu_s_per_scene']} | "
              f"{r['peak_rss_tree_gib']} | {r['load_avg_start'][0]} → {r['load_avg_end'][0]} |")
    by_count = [r for r in rows[:len(counts)]]
    if len(by_count) > 1:
        base = by_count[0]["wall_s_per_scene"]
        print("wall per scene relative to the smallest count: " + ", ".join(
            f"{r['scenes']}: {r['wall_s_per_scene'] / base:.2f}" for r in by_count))
    same = [r for r in rows if r["scenes"] == min(args.workers_at, len(ids))]
    if len(same) > 1:
        fewest = min(same, key=lambda r: r["workers"]["workers"])
        most = max(same, key=lambda r: r["workers"]["workers"])
        print(f"speed-up {fewest['workers']['workers']} → {most['workers']['workers']} workers "
              f"on {most['scenes']} scenes: {fewest['wall_s'] / most['wall_s']:.2f}× wall, "
              f"CPU {fewest['cpu_s']} → {most['cpu_s']} s")
    if json_path := args.json:
        Path(json_path).write_text(json.dumps({"machine": info, "runs": rows}, indent=1))


if __name__ == "__main__":
    main()
