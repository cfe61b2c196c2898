"""``python -m visphy_core report RUN_DIR [RUN_DIR ...] [-o OUT] [--title T]``.

One run directory gives its run report (default ``<RUN_DIR>/report/``); several give a study
report (default ``<VISPHY_HOME>/reports/study-<time>/``) that links to each run's report. Both
are folders that open from disk; the command prints the path of ``index.html``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
from pathlib import Path

from visphy_core.infra.errors import UserError


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="visphy report",
        description="Write an HTML report that opens from disk: one run directory gives a run "
                    "report, several give a study report (leaderboard, then links to each "
                    "run's report).")
    parser.add_argument("run_dirs", nargs="+", type=Path, metavar="RUN_DIR",
                        help="run directories (<VISPHY_HOME>/runs/<run>)")
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help="output folder (one run: <RUN_DIR>/report; several: "
                             "<VISPHY_HOME>/reports/study-<time>)")
    parser.add_argument("--title", default=None, help="title of a study report")
    return parser


def main(argv: list[str]) -> int:
    from visphy_core.report import write_run_report, write_study_report
    from visphy_core.results.load import load_run

    args = _parser().parse_args(argv)
    for run_dir in args.run_dirs:
        load_run(run_dir)  # a folder that is not a run: one line, before anything is written
    if len(set(p.resolve() for p in args.run_dirs)) != len(args.run_dirs):
        raise UserError("report: the same run directory is named twice")
    if len(args.run_dirs) == 1:
        if args.title:
            raise UserError("report: --title names a study report; give several run directories")
        index = write_run_report(args.run_dirs[0], args.output)
    else:
        home = Path(os.environ.get("VISPHY_HOME", "visphy-out"))
        out = args.output or home / "reports" / dt.datetime.now().strftime(
            "study-%Y-%m-%d_%H-%M-%S")
        title = args.title or f"visphy study: {len(args.run_dirs)} runs"
        index = write_study_report(list(args.run_dirs), out, title)
    print(f"report: {index}")
    return 0
