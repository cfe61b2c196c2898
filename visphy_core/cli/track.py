"""``visphy track RUN_DIR [RUN_DIR ...] [--uri URI] [--experiment NAME] [--again]``.

Logs finished run directories to MLflow after the fact, as their runs would have logged them at
their end (`visphy_core.tracking.log_finished_run`): a run whose tracking store failed (it
printed "MLflow tracking failed ... log it with: visphy track RUN_DIR"), a run made with
``tracking=none``, or runs moved to another store. The store is the one each run's config
names (``tracking.uri``, else ``<paths.root>/mlflow.db``) unless ``--uri`` says; the run's
``summary.json`` then records the MLflow run it was logged as.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from visphy_core.infra.errors import UserError


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="visphy track",
        description="Log finished run directories to MLflow (a run whose tracking failed, or "
                    "one made with tracking=none).")
    parser.add_argument("run_dirs", nargs="+", type=Path, metavar="RUN_DIR",
                        help="finished run directories (<VISPHY_HOME>/runs/<run>)")
    parser.add_argument("--uri", default=None,
                        help="tracking URI (default: the run's tracking.uri, else "
                             "sqlite:///<paths.root>/mlflow.db)")
    parser.add_argument("--experiment", default=None,
                        help="experiment name (default: the run's tracking.experiment)")
    parser.add_argument("--again", action="store_true",
                        help="log a run that its summary says is already logged")
    return parser


def cmd_track(argv: list[str]) -> int:
    from visphy_core.results.load import load_run
    from visphy_core.results.run_dir import FINISHED, RunDir
    from visphy_core.tracking import log_finished_run, mlflow_command

    args = _parser().parse_args(argv)
    runs = [load_run(p, finished=True) for p in args.run_dirs]  # every name checked first
    for run in runs:
        if run.status != FINISHED:
            raise UserError(f"track: {run.run_dir} is {run.status}: rerun its command to finish "
                            "it (it resumes where it stopped); a finished run logs itself")
    uris = set()
    for run in runs:
        logged = (run.summary.get("mlflow") or {}).get("run_id")
        if logged and not args.again:
            print(f"{run.run_dir}: already logged as MLflow run {logged} (--again logs it "
                  "once more)")
            continue
        try:
            entry = log_finished_run(run, uri=args.uri, experiment=args.experiment)
        except Exception as exc:  # noqa: BLE001 - the store's own error, as one line
            raise UserError(f"track: {run.run_dir}: MLflow failed: "
                            f"{' '.join(f'{type(exc).__name__}: {exc}'.split())[:300]}") from None
        summary = dict(run.summary, mlflow=entry)
        summary.pop("tracking_failed", None)
        RunDir(run.run_dir).write_summary(summary)
        uris.add(entry["tracking_uri"])
        print(f"{run.run_dir}: logged as MLflow run {entry['run_id']}")
    for uri in sorted(uris):
        print(f"MLflow: {mlflow_command(uri)}")
    return 0
