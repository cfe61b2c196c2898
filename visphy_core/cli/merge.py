"""``python -m visphy_core merge SHARD_RUN_DIR... -o MERGED_RUN_DIR``: the shards of one run
(``dataset.shard=i/n``) merged into one run directory and one MLflow run
(`visphy_core.execute.merge`);
``merge --study SWEEP_DIR -o OUT_DIR``: every run a study's shards belong to, each into
``OUT_DIR/<model>_<engine>_<hash8>``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from visphy_core.infra.errors import UserError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="visphy merge",
        description="Merge the run directories of one run's shards (dataset.shard=0/n … n-1/n, "
                    "same config otherwise, each finished) into one run directory: rows in the "
                    "unsharded order, summary recomputed over every scene, scene folders "
                    "hard-linked, and one MLflow run with the shards' runs as its children.",
        epilog="examples: merge RUN_A RUN_B RUN_C -o visphy-out/runs/merged · "
               "merge --study visphy-out/hydra/multirun-2026-01-01_10-00-00 -o visphy-out/merged")
    p.add_argument("shards", nargs="*", help="the shards' run directories")
    p.add_argument("-o", "--output", required=True,
                   help="the merged run directory (new); with --study, the folder that "
                        "receives one merged run per group of shards")
    p.add_argument("--study", metavar="SWEEP_DIR",
                   help="merge the shards among a study's jobs, grouped by config")
    p.add_argument("--partial", action="store_true",
                   help="merge the shards named even if some of the n are missing")
    return p


def _merge_one(shards: list[Path], out: Path, partial: bool) -> None:
    from visphy_core.execute.console import print_summary, print_where_to_look
    from visphy_core.execute.merge import merge_runs
    from visphy_core.execute.run_record import write_report

    merged = merge_runs(shards, out, partial=partial)
    summary = merged.summary
    print_summary(summary, merged.results)
    parts = ", ".join(m["shard"] for m in summary["merged_from"])
    note = (f"merged {len(summary['merged_from'])} shard(s) ({parts}): "
            f"{len(merged.results)} scenes in {merged.run_dir}")
    if merged.linked:
        note += f"; their {len(merged.linked)} MLflow run(s) are children of the merged run"
    print(note)
    print_where_to_look(write_report(merged.run_dir), merged.where_to_look)


def _merge_study(sweep_dir: Path, out_dir: Path, partial: bool) -> int:
    from visphy_core.execute.merge import merged_name, read_shard, study_groups

    groups = study_groups(sweep_dir)
    if not groups:
        raise UserError(f"merge: no completed job of {sweep_dir} is a shard (dataset.shard)")
    refused = 0
    for group in groups:
        out = out_dir / merged_name(read_shard(group[0]))
        try:
            _merge_one(group, out, partial)
        except UserError as exc:
            refused += 1
            print(f"not merged ({out.name}): {exc}", file=sys.stderr)
    if refused:
        print(f"error: merge: {refused} of {len(groups)} run(s) of {sweep_dir} not merged "
              "(above)", file=sys.stderr)
        return 2
    return 0


def cmd_merge(argv: list[str]) -> int:
    from visphy_core.api.registry import get_registry

    args = _parser().parse_args(argv)
    if bool(args.study) == bool(args.shards):
        raise UserError("merge: name either the shards' run directories or --study SWEEP_DIR")
    get_registry()
    if args.study:
        return _merge_study(Path(args.study), Path(args.output), args.partial)
    _merge_one([Path(d) for d in args.shards], Path(args.output), args.partial)
    return 0
