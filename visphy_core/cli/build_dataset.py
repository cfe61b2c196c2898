"""``python -m visphy_core build-dataset [--split S] [--seed N] [--scenes IDS] [--limit N]
[--rebuild-catalogue] …``: generate a dataset ahead of any run (the command line of
`visphy_core.execute.datasets.build_dataset`)."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path


def cmd_build_dataset(argv: list[str]) -> int:
    from visphy_core.cli.help import default_option, option_config
    from visphy_core.execute.datasets import build_dataset

    home = os.environ.get("VISPHY_HOME", "visphy-out")
    dataset = default_option("dataset")
    source = str(option_config("dataset", dataset).get("source") or dataset)
    parser = argparse.ArgumentParser(
        prog="visphy build-dataset",
        description=f"Generate a dataset that is built, not downloaded ({source} by default: "
                    "its catalogue, shipped with visphy for seed 0 and simulated for another "
                    "seed, and the clips of the requested split or scenes).")
    parser.add_argument("--source", default=source,
                        help=f"the dataset plugin (default: {source}, the source of the default "
                             f"dataset config dataset={dataset})")
    parser.add_argument("--split", default=None, help="sub, test or mini (default: all scenes)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data-dir", default=f"{home}/data")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--lossless", action="store_true",
                        help="exact-RGB clips (engine conformance) instead of the published "
                             "encoding (H.264 yuv420p crf 23)")
    parser.add_argument("--scenes", default=None,
                        help="comma-separated scene ids: only these (of the split)")
    parser.add_argument("--limit", type=int, default=None,
                        help="only N scenes of the split, those a run's dataset.limit=N takes")
    parser.add_argument("--rebuild-catalogue", action="store_true",
                        help="simulate the catalogue on this machine instead of using the one "
                             "shipped with visphy (or the one already on disk)")
    args = parser.parse_args(argv)
    if args.limit is not None and args.limit < 1:
        parser.error(f"--limit {args.limit}: must be at least 1")
    start = time.perf_counter()
    options: dict = {"lossless": True} if args.lossless else {}
    if args.rebuild_catalogue:
        options["rebuild_catalogue"] = True
    if args.scenes:
        options["scenes"] = [s.strip() for s in args.scenes.split(",") if s.strip()]
    if args.limit is not None:
        options["limit"] = args.limit
    root = build_dataset(args.source, Path(args.data_dir), seed=args.seed, split=args.split,
                         workers=args.workers, **options)
    print(f"{args.source} (seed {args.seed}, split {args.split or 'all'}) ready in {root} "
          f"({time.perf_counter() - start:.1f} s)")
    return 0
