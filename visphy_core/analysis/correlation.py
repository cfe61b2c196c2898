"""Rank agreement between runs and between judges, with p-values and the n behind each number.

**Across runs** (the cross-engine stress test, docs/studies.md): for each metric, the scene-level
Spearman ρ between every two runs over the scenes both scored, as a runs × runs matrix, and the
mean off-diagonal ρ per metric (the paper: RAFT-EPE 0.84, LPIPS 0.47, DINO 0.60). A high ρ means
the metric ranks scenes the same way whichever engine the model wrote for: it measures the
model's physics, not the engine.

**Between judges** (and humans): Pearson r and Spearman ρ between every two judge columns over
the (run, scene) rows both scored, pooled across runs.

Fewer than `MIN_N` common scenes, or a constant side, gives NaN: a coefficient of two points is
±1 by construction and says nothing. Fewer than `small_sample.MIN_SCENES` gives the number with a
warning beside it wherever it is shown (`visphy_core.analysis.small_sample`).
"""

from __future__ import annotations

import warnings
from itertools import combinations

import numpy as np
import pandas as pd
from scipy import stats

from visphy_core.analysis.column_views import MODEL_SUCCESS, scene_values
from visphy_core.results.load import RunData

MIN_N = 3
#: The paper's mean off-diagonal scene-level Spearman ρ across engines (docs/studies.md).
PAPER_MEAN_RHO = {"raft_epe": 0.84, "lpips": 0.47, "dino": 0.60}
#: visphy's stand-ins for the paper's learned metrics (other models, their own names): compared
#: with, never named as.
PAPER_PROXY = {"flow_epe_dis": "raft_epe", "st_lpips": "lpips", "dino_vits16": "dino"}


def _finite_pairs(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    keep = np.isfinite(x) & np.isfinite(y)
    return x[keep], y[keep]


def _correlation(test, x, y) -> tuple[float, float, int]:
    """(statistic, two-sided p, n) of ``test`` (a `scipy.stats` correlation) over the pairs
    where both are finite; NaN when undefined."""
    x, y = _finite_pairs(np.asarray(x, np.float64), np.asarray(y, np.float64))
    n = len(x)
    if n < MIN_N or np.ptp(x) == 0 or np.ptp(y) == 0:
        return float("nan"), float("nan"), n
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = test(x, y)
    return float(res.statistic), float(res.pvalue), n


def spearman(x, y) -> tuple[float, float, int]:
    """(ρ, two-sided p, n) over the pairs where both are finite; NaN when undefined."""
    return _correlation(stats.spearmanr, x, y)


def pearson(x, y) -> tuple[float, float, int]:
    """(r, two-sided p, n) over the pairs where both are finite; NaN when undefined."""
    return _correlation(stats.pearsonr, x, y)


def spearman_long(runs: list[RunData], labels: list[str], columns: list[str],
                  view: str = MODEL_SUCCESS) -> pd.DataFrame:
    """One row per metric and pair of runs: n common scenes, ρ, p."""
    rows = []
    for col in columns:
        values = [scene_values(r, col, view) for r in runs]
        for i, j in combinations(range(len(runs)), 2):
            ids = sorted(set(values[i].index) & set(values[j].index))
            rho, p, n = spearman(values[i].loc[ids], values[j].loc[ids])
            rows.append({"metric": col, "A": labels[i], "B": labels[j], "n": n, "ρ": rho,
                         "p": p})
    return pd.DataFrame(rows, columns=["metric", "A", "B", "n", "ρ", "p"])


def spearman_matrix(long: pd.DataFrame, labels: list[str], metric: str,
                    value: str = "ρ") -> pd.DataFrame:
    """The runs × runs matrix of ``value`` (ρ, p or n) for one metric; 1 on the diagonal for ρ."""
    m = pd.DataFrame(np.nan, index=labels, columns=labels)
    for rec in long[long["metric"] == metric].to_dict("records"):
        m.loc[rec["A"], rec["B"]] = m.loc[rec["B"], rec["A"]] = rec[value]
    if value == "ρ":
        for label in labels:
            m.loc[label, label] = 1.0
    m.index.name = "run"
    return m.reset_index()


def mean_offdiagonal(long: pd.DataFrame) -> pd.DataFrame:
    """Per metric: the mean ρ over the pairs of runs where it is defined, how many pairs that
    is, and the paper's value for the same metric (or for the one it stands in for)."""
    rows = []
    for metric, group in long.groupby("metric", sort=False):
        rho = group["ρ"].to_numpy(np.float64)
        defined = rho[np.isfinite(rho)]
        paper_metric = metric if metric in PAPER_MEAN_RHO else PAPER_PROXY.get(metric)
        rows.append({"metric": metric, "mean ρ": float(defined.mean()) if len(defined)
                     else np.nan, "pairs": int(len(defined)), "pairs total": int(len(rho)),
                     "median n": float(group["n"].median()) if len(group) else np.nan,
                     "paper ρ": PAPER_MEAN_RHO.get(paper_metric, np.nan),
                     "paper metric": paper_metric or ""})
    return pd.DataFrame(rows, columns=["metric", "mean ρ", "pairs", "pairs total", "median n",
                                       "paper ρ", "paper metric"])


def judge_agreement(runs: list[RunData], judge_columns: list[str],
                    human: bool = True) -> pd.DataFrame:
    """Pearson and Spearman between every two judges (and each judge with the humans' mean
    rating per scene when any run has ratings), pooled over every run's scenes."""
    from visphy_core.analysis.human import scene_means

    frames = []
    for run in runs:
        results = run.table
        if results.empty:
            continue
        df = pd.DataFrame(index=pd.Index(results["scene_id"].to_numpy(), name="scene_id"))
        for c in judge_columns:
            key = f"score_{c}"
            df[c] = (pd.to_numeric(results[key], errors="coerce").to_numpy(np.float64)
                     if key in results.columns else np.nan)
        if human and len(run.ratings):
            df["human"] = scene_means(run.ratings).reindex(df.index)
        frames.append(df.reset_index(drop=True))
    pooled = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    names = [c for c in [*judge_columns, "human"] if c in pooled.columns]
    rows = []
    for a, b in combinations(names, 2):
        x, y = pooled[a].to_numpy(np.float64), pooled[b].to_numpy(np.float64)
        r, rp, n = pearson(x, y)
        rho, sp, _ = spearman(x, y)
        rows.append({"A": a, "B": b, "n": n, "pearson r": r, "pearson p": rp,
                     "spearman ρ": rho, "spearman p": sp})
    return pd.DataFrame(rows, columns=["A", "B", "n", "pearson r", "pearson p", "spearman ρ",
                                       "spearman p"])
