"""Full VisPhyBench build time on this machine (target: ≤ 10 minutes on 2 cores).

    .venv/bin/python benchmarks/bench_build.py [--data-dir /tmp/visphy-bench-build] [--workers 2]
        [--ground-truth threejs [--metrics default]] [--shipped-catalogue]

Builds from scratch (the data dir is wiped first) and prints the catalogue time (simulate and
annotate every candidate, even for the seed whose catalogue ships with visphy; with
``--shipped-catalogue`` a first run's copy of it instead), the render time, peak memory, and the
per-dimension scene counts.
``--ground-truth ENGINE`` then times the ground-truth step of the built split as a user runs it
(``python -m visphy_core ground-truth dataset=visphybench engine=ENGINE metrics=…`` in a
subprocess, the store in ``<data-dir>/ground_truth``): the twins rendered and every metric's
anchors, which every later run of any model on that data dir reuses.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--data-dir", default="/tmp/visphy-bench-build")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ground-truth", metavar="ENGINE",
                        help="also compute the split's ground-truth artefacts for ENGINE")
    parser.add_argument("--metrics", default="default", help="the suite they are for")
    parser.add_argument("--shipped-catalogue", action="store_true",
                        help="use the catalogue shipped with visphy (seed 0) as a run does")
    args = parser.parse_args()

    from visphy_plugins.datasets.visphybench.build import build_dataset

    data_dir = Path(args.data_dir)
    shutil.rmtree(data_dir, ignore_errors=True)
    start = time.perf_counter()
    root = build_dataset(data_dir, seed=args.seed, workers=args.workers,
                         rebuild_catalogue=not args.shipped_catalogue)
    total = time.perf_counter() - start
    times = json.loads((root / "build_times.json").read_text())
    metas = [json.loads(line) for line in (root / "metadata.jsonl").read_text().splitlines()]
    summary = {
        "total_s": round(total, 1),
        "catalogue_s": times.get("catalogue_s"),
        "render_s": times.get("render_all_s"),
        "scenes": len(metas),
        "scenes_2d": sum(m["dim"] == "2d" for m in metas),
        "scenes_3d": sum(m["dim"] == "3d" for m in metas),
        "workers": args.workers,
        "peak_rss_main_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "peak_rss_children_mib": round(
            resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, 1),
        "root": str(root),
    }
    if args.ground_truth:
        summary["ground_truth"] = ground_truth(data_dir, args.ground_truth, args.metrics,
                                               args.workers)
    print(json.dumps(summary, indent=1))


def ground_truth(data_dir: Path, engine: str, metrics: str, workers: int) -> dict:
    """The ground-truth step as a subprocess: its wall time, CPU seconds and peak RSS."""
    import subprocess
    import sys
    import tempfile

    repo = Path(__file__).resolve().parents[1]
    cache = tempfile.mkdtemp(prefix="visphy-bench-gt-cache-")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "visphy_core", "ground-truth", "--workers", str(workers),
         "dataset=visphybench", f"engine={engine}", f"metrics={metrics}",
         f"paths.data_dir={data_dir}", f"paths.cache_dir={cache}"],
        cwd=repo, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"ground-truth failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return {"engine": engine, "metrics": metrics, "wall_s": round(wall, 1),
            "cpu_s": round(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime,
                           1),
            "peak_rss_mib": round(after.ru_maxrss / 1024, 1),
            "output": proc.stdout.strip().splitlines()[-1:]}


if __name__ == "__main__":
    main()
