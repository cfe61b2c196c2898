"""The leaderboard: one row per run, success rates, and each metric in both success views with
its count (model success by default, the fallbacks, and honest denominators).

Per metric ``m`` with direction arrow ``a``: ``m a`` (mean over the model's own successes),
``m n`` (how many scenes that mean is over), ``m a +fb`` and ``m n +fb`` (fallback clips scored
too). Means are recomputed from the scene rows, so they agree with ``summary.json`` and with
every other table made from the same rows. With human ratings: ``human ↑`` (mean over rated
scenes of each scene's mean 1–5 rating), ``human n`` (ratings), ``human raters`` and
``human α`` (ordinal Krippendorff's alpha between raters).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from visphy_core.analysis.column_views import MODEL_SUCCESS, WITH_FALLBACKS, header, scene_values
from visphy_core.analysis.human import summarise_ratings
from visphy_core.results.load import RunData
from visphy_core.results.row import NOT_EVALUABLE


def _rate(num: int, den: int) -> float:
    return num / den if den else float("nan")


def run_columns(run: RunData, label: str) -> dict:
    """The leaderboard's fixed columns for one run."""
    df = run.table
    n = len(df)
    evaluable = int((~df["failure_class"].isin(NOT_EVALUABLE)).sum()) if n else 0
    model_ok = int(df["model_success"].sum()) if n else 0
    system_ok = int(df["system_success"].sum()) if n else 0
    return {"run": label, "model": run.model, "engine": run.engine,
            "dataset": str((run.config.get("dataset") or {}).get("name")
                           or run.summary.get("dataset") or ""),
            "n_scenes": n, "n_evaluable": evaluable,
            "model success rate": _rate(model_ok, n),
            "system success rate": _rate(system_ok, n),
            "fallbacks": int(df["fallback"].sum()) if n else 0}


def leaderboard(runs: list[RunData], labels: list[str], columns: list[str]) -> pd.DataFrame:
    """One row per run: `run_columns`, then ``columns`` in both views, then Human when any run
    has ratings."""
    rows = []
    any_ratings = any(len(r.ratings) for r in runs)
    for run, label in zip(runs, labels):
        row = run_columns(run, label)
        for col in columns:
            head = header(runs, col)
            for view, suffix in ((MODEL_SUCCESS, ""), (WITH_FALLBACKS, " +fb")):
                values = scene_values(run, col, view)
                row[f"{head}{suffix}"] = float(values.mean()) if len(values) else np.nan
                row[f"{col} n{suffix}"] = int(len(values))
        if any_ratings:
            human = summarise_ratings(run.ratings)
            row.update({"human ↑": human["mean"], "human n": human["n"],
                        "human raters": human["raters"], "human α": human["alpha"]})
        rows.append(row)
    return pd.DataFrame(rows)


def printed_columns(table: pd.DataFrame, runs: list[RunData], columns: list[str]) -> list[str]:
    """The compact subset for a terminal or a paper: the run, success, fallbacks, and each
    metric's model-success mean and count (human columns when present)."""
    keep = ["run", "n_scenes", "model success rate", "fallbacks"]
    for col in columns:
        keep += [header(runs, col), f"{col} n"]
    keep += [c for c in ("human ↑", "human n", "human α") if c in table.columns]
    return [c for c in keep if c in table.columns]
