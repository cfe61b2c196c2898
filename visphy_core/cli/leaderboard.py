"""``visphy leaderboard RUN_OR_STUDY... -o SITE [--reference FILE] [--labels FILE]``.

A static site (plain HTML, CSS, SVG and a small inline script; nothing fetched) from finished
runs and study folders: it opens from disk and deploys as it is to any static host. See
`visphy_core.leaderboard` and docs/results/leaderboard.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from visphy_core.infra.errors import UserError


def _parser() -> argparse.ArgumentParser:
    from visphy_core.leaderboard.clips import MAX_CLIP_MB, MAX_REPORT_MB

    parser = argparse.ArgumentParser(
        prog="visphy leaderboard",
        description="Write a static leaderboard site from finished runs (and study folders "
                    "holding runs): one row per run with the headline and its 95 % interval, "
                    "tie ranks from a paired bootstrap over shared scenes, breakdowns, each "
                    "run's report and its best and worst clips, and a page per metric.")
    parser.add_argument("paths", nargs="+", type=Path, metavar="RUN_OR_STUDY",
                        help="run directories, study folders or any folder holding runs")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="SITE",
                        help="output folder (new, empty, or an earlier site to rebuild)")
    parser.add_argument("--title", default="visphy leaderboard", help="the site's title")
    parser.add_argument("--reference", type=Path, action="append", default=[], metavar="FILE",
                        help="reference rows (published numbers) from a .yaml, .json or .csv "
                             "file, each with model and source; shown apart, never ranked "
                             "(repeatable)")
    parser.add_argument("--labels", type=Path, default=None, metavar="FILE",
                        help="scene labels for a breakdown: .csv, .json or .jsonl rows with "
                             "scene_id and label (or family), e.g. the dataset's "
                             "metadata.jsonl")
    parser.add_argument("--clips", type=int, default=2, metavar="N",
                        help="best and worst scenes shown side by side per row (default 2)")
    parser.add_argument("--max-clip-mb", type=float, default=MAX_CLIP_MB, metavar="MB",
                        help=f"leave out clips larger than this (default {MAX_CLIP_MB:g})")
    parser.add_argument("--max-report-mb", type=float, default=MAX_REPORT_MB, metavar="MB",
                        help="leave out a copied report's largest clips until its media fit "
                             f"(default {MAX_REPORT_MB:g})")
    parser.add_argument("--no-reports", action="store_true",
                        help="do not copy the run reports (rows link to no report)")
    return parser


def main(argv: list[str]) -> int:
    from visphy_core.leaderboard import SiteOptions, build_site
    from visphy_core.leaderboard.breakdowns import read_labels
    from visphy_core.leaderboard.references import read_references

    args = _parser().parse_args(argv)
    if args.clips < 0:
        raise UserError("leaderboard: --clips is 0 or more")
    if args.max_clip_mb <= 0 or args.max_report_mb <= 0:
        raise UserError("leaderboard: --max-clip-mb and --max-report-mb are positive")
    references = [r for path in args.reference for r in read_references(path)]
    options = SiteOptions(title=args.title, references=references,
                          labels=read_labels(args.labels) if args.labels else None,
                          clips_per_side=args.clips, max_clip_mb=args.max_clip_mb,
                          max_report_mb=args.max_report_mb, with_reports=not args.no_reports)
    site = build_site(list(args.paths), args.output, options)
    for line in site.warnings:
        print(f"warning: {line}")
    print(f"leaderboard: {site.index}")
    return 0
