"""Time to write a run's HTML report, the first time and again (unchanged run).

    .venv/bin/python benchmarks/bench_report.py RUN_DIR [--repeats 3]

The first write copies (or transcodes) every clip and key frame into a fresh report folder (a
temporary one: the run's own ``report/`` is left alone); a rewrite of an unchanged run copies
nothing again (tests/test_report.py asserts that) and only re-renders the page. Target: a
rewrite of a small run (two scenes) under 2 s on an idle core. Prints the median of
``--repeats`` writes of each kind.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from visphy_core.report.run_report import write_run_report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    first, again = [], []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="visphy-bench-report-") as tmp:
            out = Path(tmp) / "report"
            start = time.perf_counter()
            write_run_report(args.run_dir, out)
            first.append(time.perf_counter() - start)
            start = time.perf_counter()
            write_run_report(args.run_dir, out)
            again.append(time.perf_counter() - start)
    print(json.dumps({"run_dir": str(args.run_dir), "repeats": args.repeats,
                      "first_write_s": round(statistics.median(first), 3),
                      "rewrite_s": round(statistics.median(again), 3),
                      "rewrite_target_s": 2.0}, indent=1))


if __name__ == "__main__":
    main()
