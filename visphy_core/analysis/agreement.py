"""Krippendorff's alpha: agreement between raters on the same items, chance-corrected.

Alpha fits human 1–5 ratings where raters see different subsets of items (missing values are
the norm, not the exception) and the scale is ordinal (a 4 is closer to a 5 than a 1 is). The
implementation follows Krippendorff (2011), "Computing Krippendorff's Alpha-Reliability": build
the coincidence matrix over pairable values (units with at least two ratings), then
``alpha = 1 - D_o / D_e`` with the level's squared distance δ². Checked against a hand-computed
example and the paper's worked ordinal example (α = 0.815) in tests/test_analysis_units.py.
"""

from __future__ import annotations

import numpy as np

LEVELS = ("nominal", "ordinal", "interval")


def coincidences(reliability: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sorted distinct values and the coincidence matrix ``o[c, k]`` of a coders × units
    array (NaN = not rated): each unit with m ≥ 2 ratings adds its ordered pairs of ratings
    (from different coders), weighted 1 / (m − 1)."""
    data = np.asarray(reliability, dtype=np.float64)
    if data.ndim != 2:
        raise ValueError("reliability data must be a coders × units array")
    values = np.unique(data[~np.isnan(data)])
    # counts[u, v]: how many coders gave value v to unit u
    idx = np.searchsorted(values, np.where(np.isnan(data), values[0] if len(values) else 0, data))
    counts = np.zeros((data.shape[1], len(values)))
    for coder in range(data.shape[0]):
        rated = ~np.isnan(data[coder])
        np.add.at(counts, (np.nonzero(rated)[0], idx[coder][rated]), 1.0)
    m = counts.sum(axis=1)
    pairable = m >= 2
    c = counts[pairable]
    weights = 1.0 / (m[pairable] - 1.0)
    o = (c * weights[:, None]).T @ c - np.diag((c * weights[:, None]).sum(axis=0))
    return values, o


def distance2(values: np.ndarray, n_c: np.ndarray, level: str) -> np.ndarray:
    """The squared distance δ²(c, k) between every two values under ``level``; ordinal uses the
    marginal counts ``n_c``: (Σ_{g=c..k} n_g − (n_c + n_k)/2)²."""
    if level == "nominal":
        return 1.0 - np.eye(len(values))
    if level == "interval":
        return (values[:, None] - values[None, :]) ** 2
    if level == "ordinal":
        cum = np.cumsum(n_c)
        lo = np.minimum.outer(np.arange(len(values)), np.arange(len(values)))
        hi = np.maximum.outer(np.arange(len(values)), np.arange(len(values)))
        between = cum[hi] - cum[lo] + n_c[lo]
        return (between - (n_c[:, None] + n_c[None, :]) / 2.0) ** 2
    raise ValueError(f"unknown level of measurement {level!r} (one of {', '.join(LEVELS)})")


def krippendorff_alpha(reliability: np.ndarray, level: str = "ordinal") -> float:
    """Krippendorff's alpha of a coders × units array (NaN = not rated).

    NaN when it is undefined: no unit has two ratings, or all pairable ratings are one value
    (no disagreement is expected, so none can be corrected for).
    """
    values, o = coincidences(reliability)
    n_c = o.sum(axis=0)
    n = n_c.sum()
    if n <= 1 or len(values) < 2:
        return float("nan")
    d2 = distance2(values, n_c, level)
    expected = float((np.outer(n_c, n_c) * d2).sum()) / (n - 1.0)
    if expected == 0:
        return float("nan")
    observed = float((o * d2).sum())
    return 1.0 - observed / expected
