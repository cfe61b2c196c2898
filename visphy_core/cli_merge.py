"""``python -m visphy_core merge SHARD_RUN_DIR... -o MERGED_RUN_DIR``: the shards of one run
(``dataset.shard=i/n``) merged into one run directory and one MLflow run (`visphy_core.merge`)."""

from __future__ import annotations

import argparse
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m visphy_core merge",
        description="Merge the run directories of one run's shards (dataset.shard=0/n … n-1/n, "
                    "same config otherwise, each finished) into one run directory: rows in the "
                    "unsharded order, summary recomputed over every scene, scene folders "
                    "hard-linked, and one MLflow run with the shards' runs as its children.",
        epilog="example: merge visphy-out/runs/*_oracle_threejs_* -o visphy-out/runs/merged "
               "(a shell glob may name other runs too: merge refuses them by config)")
    p.add_argument("shards", nargs="+", help="the shards' run directories")
    p.add_argument("-o", "--output", required=True, help="the merged run directory (new)")
    p.add_argument("--partial", action="store_true",
                   help="merge the shards named even if some of the n are missing")
    return p


def cmd_merge(argv: list[str]) -> int:
    from visphy_core.console import print_summary, print_where_to_look
    from visphy_core.merge import merge_runs
    from visphy_core.plugins import get_registry
    from visphy_core.run import write_report

    args = _parser().parse_args(argv)
    get_registry()
    merged = merge_runs([Path(d) for d in args.shards], Path(args.output), partial=args.partial)
    summary = merged.summary
    print_summary(summary, merged.results)
    shards = ", ".join(m["shard"] for m in summary["merged_from"])
    note = f"merged {len(summary['merged_from'])} shard(s) ({shards}): {len(merged.results)} "
    note += f"scenes in {merged.run_dir}"
    if merged.linked:
        note += f"; their {len(merged.linked)} MLflow run(s) are children of the merged run"
    print(note)
    print_where_to_look(write_report(merged.run_dir),
                        (summary.get("mlflow") or {}).get("tracking_uri"))
    return 0
