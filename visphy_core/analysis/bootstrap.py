"""Paired bootstrap over scenes: is configuration A better than B on a metric, and by how much?

Scenes are the unit of resampling (docs/studies.md): only the scenes both runs scored under the
chosen view are compared (their number is reported), the per-scene differences are resampled
with replacement ``resamples`` times (one seeded generator, so the same inputs always give the
same interval), and the 95% interval is the 2.5th–97.5th percentile of the resampled mean
differences. The two-sided p-value is twice the smaller tail of that distribution on either side
of zero, with the +1 correction (never exactly 0 from a finite number of resamples).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
import pandas as pd

from visphy_core.analysis.column_views import MODEL_SUCCESS, direction, header, scene_values
from visphy_core.results.load import RunData

RESAMPLES = 10_000
SEED = 0


@dataclass(frozen=True)
class PairedDifference:
    """mean(a) − mean(b) over ``n`` common scenes, its 95% interval and two-sided p."""

    n: int
    mean_a: float
    mean_b: float
    diff: float
    ci_low: float
    ci_high: float
    p: float


def resample_indices(n: int, resamples: int = RESAMPLES, seed: int = SEED) -> np.ndarray:
    """The resamples × n scene indices drawn with replacement (the same for the same
    arguments: every comparison of n scenes resamples the same way)."""
    return np.random.default_rng(seed).integers(0, n, size=(resamples, n))


def paired_bootstrap(a: np.ndarray, b: np.ndarray, resamples: int = RESAMPLES,
                     seed: int = SEED, level: float = 0.95,
                     indices: np.ndarray | None = None) -> PairedDifference:
    """The paired bootstrap of mean(a − b) for equally long, scene-aligned arrays (vectorised:
    one resamples × n index draw, or ``indices`` from `resample_indices`)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError("paired samples must be two 1-D arrays of the same length")
    n = len(a)
    if n == 0:
        nan = float("nan")
        return PairedDifference(0, nan, nan, nan, nan, nan, nan)
    d = a - b
    if indices is None:
        indices = resample_indices(n, resamples, seed)
    means = d[indices].mean(axis=1)
    tail = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [tail, 1.0 - tail])
    below = (np.count_nonzero(means <= 0) + 1) / (resamples + 1)
    above = (np.count_nonzero(means >= 0) + 1) / (resamples + 1)
    return PairedDifference(n=n, mean_a=float(a.mean()), mean_b=float(b.mean()),
                            diff=float(d.mean()), ci_low=float(lo), ci_high=float(hi),
                            p=float(min(1.0, 2.0 * min(below, above))))


def common(run_a: RunData, run_b: RunData, column: str, view: str
           ) -> tuple[np.ndarray, np.ndarray]:
    """The two runs' values on the scenes both scored, in the same scene order."""
    va, vb = scene_values(run_a, column, view), scene_values(run_b, column, view)
    ids = sorted(set(va.index) & set(vb.index))
    return va.loc[ids].to_numpy(np.float64), vb.loc[ids].to_numpy(np.float64)


def bootstrap_table(runs: list[RunData], labels: list[str], columns: list[str],
                    view: str = MODEL_SUCCESS, resamples: int = RESAMPLES,
                    seed: int = SEED) -> pd.DataFrame:
    """Every pair of runs × every column: n common scenes, both means, A − B with its 95% CI
    and p, and which run is better when the interval excludes 0 (by the metric's direction)."""
    rows = []
    draws: dict[int, np.ndarray] = {}
    for (i, ra), (j, rb) in combinations(enumerate(runs), 2):
        for col in columns:
            a, b = common(ra, rb, col, view)
            if len(a) and len(a) not in draws:
                draws[len(a)] = resample_indices(len(a), resamples, seed)
            r = paired_bootstrap(a, b, resamples, seed, indices=draws.get(len(a)))
            better = ""
            way = direction(runs, col)
            if r.n and way and not (r.ci_low <= 0 <= r.ci_high):
                a_wins = (r.diff > 0) == (way == "higher")
                better = labels[i] if a_wins else labels[j]
            rows.append({"metric": header(runs, col), "A": labels[i], "B": labels[j],
                         "n common": r.n, "mean A": r.mean_a, "mean B": r.mean_b,
                         "A − B": r.diff, "CI low": r.ci_low, "CI high": r.ci_high,
                         "p": r.p, "better": better})
    return pd.DataFrame(rows, columns=["metric", "A", "B", "n common", "mean A", "mean B",
                                       "A − B", "CI low", "CI high", "p", "better"])
