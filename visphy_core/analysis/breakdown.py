"""Where runs succeed and fail: by difficulty and dimension, and by failure class.

The difficulty breakdown splits every run's scenes by ``difficulty`` (easy / medium / hard, the
benchmark's 1–5 ratings binned) and by ``dim`` (2D / 3D) and gives, per group, the
scene count, the model-success rate and each metric's mean with its count. The failure table
counts why the model's program gave no clip, per class, with ``infra_error`` and ``data_error``
set apart: they are our side's or the scene's fault and leave the scene not evaluable.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from visphy_core.analysis.column_views import MODEL_SUCCESS, header, view_rows
from visphy_core.api.engine import FailureClass
from visphy_core.results.load import RunData
from visphy_core.results.row import NOT_EVALUABLE

DIFFICULTY_ORDER = ("easy", "medium", "hard")
NOT_EVALUABLE_SUFFIX = " (not evaluable)"


def _groups(df: pd.DataFrame) -> list[tuple[str, str, pd.Series]]:
    out = []
    if "difficulty" in df.columns:
        present = [d for d in df["difficulty"].dropna().unique()]
        for value in sorted(present, key=lambda d: (DIFFICULTY_ORDER.index(d)
                                                     if d in DIFFICULTY_ORDER else 9, d)):
            out.append(("difficulty", str(value), df["difficulty"] == value))
    if "dim" in df.columns:
        for value in sorted(df["dim"].dropna().unique()):
            out.append(("dim", str(value).upper(), df["dim"] == value))
    return out


def difficulty_table(runs: list[RunData], labels: list[str], columns: list[str],
                     view: str = MODEL_SUCCESS) -> pd.DataFrame:
    """One row per run × group (difficulty level, then dimension)."""
    rows = []
    for run, label in zip(runs, labels):
        df = run.table
        if df.empty:
            continue
        for group, value, mask in _groups(df):
            sub = df[mask]
            row = {"run": label, "by": group, "group": value, "n_scenes": int(len(sub)),
                   "model success rate": float(sub["model_success"].mean())
                   if len(sub) else np.nan}
            for col in columns:
                key = f"score_{col}"
                chosen = mask & view_rows(run, col, view)
                vals = pd.to_numeric(df.loc[chosen, key], errors="coerce").dropna() \
                    if key in df.columns else pd.Series(dtype="float64")
                row[header(runs, col)] = float(vals.mean()) if len(vals) else np.nan
                row[f"{col} n"] = int(len(vals))
            rows.append(row)
    return pd.DataFrame(rows)


def failure_table(runs: list[RunData], labels: list[str]) -> pd.DataFrame:
    """One row per run: scenes, evaluable scenes, model successes, repairs, fallbacks, then the
    model's failures per class and the not-evaluable ones (every class any run has)."""
    order = [c.value for c in FailureClass]
    seen: set[str] = set()
    counts = []
    for run in runs:
        df = run.table
        failed = df[~df["model_success"].astype(bool)] if len(df) else df
        c = failed["failure_class"].dropna().value_counts().to_dict() if len(failed) else {}
        seen |= set(c)
        counts.append(c)
    model_classes = [k for k in order if k in seen and k not in NOT_EVALUABLE]
    model_classes += sorted(k for k in seen if k not in order)
    rows = []
    for run, label, c in zip(runs, labels, counts):
        df = run.table
        n = len(df)
        ok = df["model_success"].astype(bool) if n else pd.Series(dtype=bool)
        row = {"run": label, "n_scenes": n,
               "n_evaluable": int((~df["failure_class"].isin(NOT_EVALUABLE)).sum()) if n else 0,
               "model success": int(ok.sum()) if n else 0,
               "repaired": int((ok & (df["attempts"] > 1)).sum()) if n else 0,
               "fallbacks": int(df["fallback"].sum()) if n else 0}
        for k in model_classes:
            row[k] = int(c.get(k, 0))
        for k in NOT_EVALUABLE:
            row[k + NOT_EVALUABLE_SUFFIX] = int(c.get(k, 0))
        rows.append(row)
    return pd.DataFrame(rows)
