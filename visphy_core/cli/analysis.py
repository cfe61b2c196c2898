"""``python -m visphy_core analyse PATH... [-o OUT] [--study NAME] [--metrics a,b]``: the tables
and figures of finished runs (`visphy_core.analysis.study.analyse`), printed and written."""

from __future__ import annotations

import argparse
import datetime as dt
import os
from pathlib import Path


def cmd_analyse(argv: list[str]) -> int:
    from visphy_core.analysis.bootstrap import RESAMPLES
    from visphy_core.analysis.column_views import VIEWS
    from visphy_core.analysis.study import STUDIES

    parser = argparse.ArgumentParser(
        prog="visphy analyse",
        description="Leaderboard, paired bootstrap CIs, Spearman matrices, judge agreement, "
                    "breakdowns and figures from finished runs (CSV, Markdown, LaTeX, PNG, SVG).")
    parser.add_argument("paths", nargs="+", metavar="PATH",
                        help="run directories, or folders holding them (a sweep, "
                             "visphy-out/runs)")
    parser.add_argument("-o", "--output", default=None,
                        help="output folder (default: $VISPHY_HOME/analysis/<time>)")
    parser.add_argument("--study", choices=sorted(STUDIES), default=None,
                        help="the tables that study needs (default: all that apply)")
    parser.add_argument("--metrics", default=None,
                        help="comma-separated score columns to compare (default: headline)")
    parser.add_argument("--view", choices=VIEWS, default=VIEWS[0],
                        help="scenes each comparison uses (default: model_success)")
    parser.add_argument("--resamples", type=int, default=RESAMPLES,
                        help=f"bootstrap resamples (default {RESAMPLES})")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    args = parser.parse_args(argv)

    from visphy_core.analysis.load import load_runs
    from visphy_core.analysis.printing import print_study
    from visphy_core.analysis.study import analyse
    from visphy_core.infra.errors import UserError

    if args.resamples < 100:
        raise UserError(f"--resamples {args.resamples}: use at least 100")
    runs = load_runs(args.paths)
    out = Path(args.output) if args.output else (
        Path(os.environ.get("VISPHY_HOME", "visphy-out")) / "analysis"
        / dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S"))
    metrics = [m.strip() for m in args.metrics.split(",") if m.strip()] if args.metrics else None
    outputs = analyse(runs, out, study=args.study, metrics=metrics, view=args.view,
                      resamples=args.resamples, seed=args.seed)
    print_study(outputs, out_dir=out.resolve())
    return 0
