"""Score columns across runs: which exist, which way is better, which to show by default, and
each scene's values in either success view.

A run's ``results`` carry one ``score_<column>`` per metric column (``psnr``, ``psnr.aligned``,
``paper.psnr``, ``spec.…``, ``norm.…``, ``judge_<key>``); its ``summary.json`` gives each
column's direction. The two views follow `visphy_core.results.summary.summarise`: **model
success** (the model's own program gave the clip) and **with fallbacks** (every scene with a
clip; the spec track's ``spec.`` columns over every evaluable scene, as S is scored whether or
not the program ran).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from visphy_core.infra.errors import UserError
from visphy_core.results.columns import JUDGE_PREFIX, NORM_PREFIX, SCORE, SPEC_PREFIX
from visphy_core.results.row import NOT_EVALUABLE

if TYPE_CHECKING:
    from visphy_core.results.load import RunData

MODEL_SUCCESS, WITH_FALLBACKS = "model_success", "with_fallbacks"
VIEWS = (MODEL_SUCCESS, WITH_FALLBACKS)
ARROW = {"higher": "↑", "lower": "↓"}

#: The printed leaderboard's metrics, in order, when present: pixels and perception, semantics,
#: motion (flow, tracks, events), then the judges (``judge_*``) and humans.
HEADLINE = ("psnr", "ssim", "lpips", "st_lpips", "dists", "clip_img", "dino",
            "raft_epe", "flow_epe_dis", "track_pos_err", "track_vel_err", "event_contact_err")


def score_columns(runs: list["RunData"]) -> list[str]:
    """Every score column any run has, in first-seen order."""
    out: dict[str, None] = {}
    for run in runs:
        for name in run.summary.get("metrics", {}):
            out[name] = None
        for col in run.table.columns:
            if col.startswith(SCORE):
                out[col[len(SCORE):]] = None
    return list(out)


def direction(runs: list["RunData"], column: str) -> str | None:
    """``higher`` or ``lower`` as the runs' summaries declare it (judges and human: higher)."""
    for run in runs:
        info = run.summary.get("metrics", {}).get(column)
        if isinstance(info, dict) and info.get("direction") in ARROW:
            return info["direction"]
    if column.startswith((JUDGE_PREFIX, "human", NORM_PREFIX, SPEC_PREFIX + NORM_PREFIX)):
        return "higher"
    return None


def header(runs: list["RunData"], column: str) -> str:
    """``psnr ↑``: the column with its direction arrow."""
    arrow = ARROW.get(direction(runs, column) or "", "")
    return f"{column} {arrow}".strip()


def has_values(runs: list["RunData"], column: str) -> bool:
    return any(SCORE + column in r.table.columns and r.table[SCORE + column].notna().any()
               for r in runs)


def unavailable_reason(runs: list["RunData"], column: str) -> str | None:
    for run in runs:
        info = run.summary.get("metrics", {}).get(column)
        if isinstance(info, dict) and info.get("unavailable"):
            return str(info["unavailable"])
    return None


def headline_columns(runs: list["RunData"]) -> list[str]:
    """The default metric subset: the runs' headline score (``summary.json``'s
    ``headline.metric``, ``physics_score`` by default) first, then the `HEADLINE` metrics with
    values, then every judge column."""
    scores = dict.fromkeys(str((run.summary.get("headline") or {}).get("metric") or "")
                           for run in runs)
    cols = [c for c in scores if c and c not in HEADLINE and has_values(runs, c)]
    cols += [c for c in HEADLINE if has_values(runs, c)]
    judges = [c for c in score_columns(runs) if c.startswith(JUDGE_PREFIX) and has_values(runs, c)]
    return cols + judges


def pick_columns(runs: list["RunData"], metrics: list[str] | None) -> list[str]:
    """``metrics`` checked against the runs' columns (`UserError` naming the unknown ones and
    what exists), else the headline subset."""
    if not metrics:
        return headline_columns(runs)
    known = score_columns(runs)
    unknown = [m for m in metrics if m not in known]
    if unknown:
        raise UserError(f"unknown metric column(s) {', '.join(unknown)}; these runs have: "
                        f"{', '.join(known) or 'none'}")
    return list(metrics)


def view_rows(run: "RunData", column: str, view: str) -> pd.Series:
    """Which rows count for ``column`` under ``view`` (boolean mask over ``run.table``)."""
    df = run.table
    if view not in VIEWS:
        raise UserError(f"unknown view {view!r} (one of {', '.join(VIEWS)})")
    if df.empty:
        return pd.Series(dtype=bool)
    if view == MODEL_SUCCESS:
        return df["model_success"].fillna(False).astype(bool)
    if column.startswith(SPEC_PREFIX):
        return ~df["failure_class"].isin(NOT_EVALUABLE)
    return df["system_success"].fillna(False).astype(bool)


def scene_values(run: "RunData", column: str, view: str = MODEL_SUCCESS) -> pd.Series:
    """The column's per-scene values under ``view``, indexed by scene_id, missing ones dropped."""
    df = run.table
    if df.empty or SCORE + column not in df.columns:
        return pd.Series(dtype="float64", name=column)
    mask = view_rows(run, column, view)
    values = pd.to_numeric(df.loc[mask, SCORE + column], errors="coerce")
    values.index = df.loc[mask, "scene_id"]
    values = values[np.isfinite(values.to_numpy(dtype=np.float64))]
    return values.rename(column)
