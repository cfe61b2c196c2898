"""``python -m visphy_core ground-truth [--workers N] [overrides]``: the command line of
`visphy_core.execute.prepare_truth.prepare` (a dataset's ground-truth artefacts computed ahead
of any run into the ground-truth store)."""

from __future__ import annotations

import argparse


def cmd_ground_truth(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="visphy ground-truth",
        description="Compute the ground-truth artefacts of a dataset's scenes ahead of any run "
                    "(the twin's render and the normalisation anchors of every metric) into "
                    "the ground-truth store (paths.ground_truth_dir). Takes a run's overrides: "
                    "dataset=…, engine=…, metrics=….")
    parser.add_argument("--workers", type=int, default=2,
                        help="scenes in flight (one renders while the others score)")
    parser.add_argument("overrides", nargs="*", default=[], help="Hydra overrides, as for a run")
    args = parser.parse_args(argv)
    from visphy_core.execute.prepare_truth import prepare

    return prepare(args.overrides, workers=max(1, args.workers))
