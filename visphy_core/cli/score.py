"""``python -m visphy_core score RUN_DIR [overrides] [--in-place]``: re-score a finished run
with other metrics or judges, without calling the model or rendering
(`visphy_core.execute.rescore`)."""

from __future__ import annotations

import argparse
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    from visphy_core.cli.help import config_options, default_option

    judges = [j for j in config_options().get("judge", []) if j != default_option("judge")]
    first, second = (judges + ["JUDGE", "JUDGE"])[:2]
    p = argparse.ArgumentParser(
        prog="visphy score",
        description="Score a finished (or interrupted) run again: other metrics, judges, "
                    "reference descriptions, tracking. No model call, no render; scores "
                    "already computed come from the cache. The results go to a new run "
                    "directory <name>.rescored-<time> beside the original (or into the run "
                    "itself with --in-place, after a backup).",
        epilog="examples: score RUN metrics.names=[psnr,ssim,flow_epe_dis] · "
               f"score RUN judge={first} · score RUN +judge={second} · score RUN metrics=full")
    p.add_argument("run_dir", help="the run directory (under <VISPHY_HOME>/runs/)")
    p.add_argument("overrides", nargs="*", default=[],
                   help="Hydra overrides of what scoring reads: metrics=…, metrics.*, judge=…, "
                        "+judge=…, judge.<key>.*, reference.*, tracking=…, tracking.*, "
                        "paths.data_dir, paths.cache_dir, run.progress, run.cache")
    p.add_argument("--in-place", action="store_true",
                   help="rewrite the run itself (what changes is backed up first under "
                        "rescore-backup-<time>/)")
    return p


def cmd_score(argv: list[str]) -> int:
    from visphy_core.api.registry import get_registry
    from visphy_core.execute.rescore import rescore_run

    args = _parser().parse_intermixed_args(argv)
    get_registry()  # plugins store their structured configs before Hydra composes
    rescore_run(Path(args.run_dir), list(args.overrides), in_place=args.in_place)
    return 0
