"""Full VisPhyBench build time on this machine (target: ≤ 10 minutes on 2 cores).

    .venv/bin/python benchmarks/bench_build.py [--data-dir /tmp/visphy-bench-build] [--workers 2]

Builds from scratch (the data dir is wiped first) and prints the catalogue time (simulate and
annotate every candidate), the render time, peak memory, and the per-dimension scene counts.
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
    args = parser.parse_args()

    from visphy_plugins.datasets.visphybench.build import build_dataset

    data_dir = Path(args.data_dir)
    shutil.rmtree(data_dir, ignore_errors=True)
    start = time.perf_counter()
    root = build_dataset(data_dir, seed=args.seed, workers=args.workers)
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
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
