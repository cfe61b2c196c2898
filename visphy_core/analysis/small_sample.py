"""Small-sample honesty: which numbers rest on fewer than `MIN_SCENES` common scenes.

A Spearman ρ over 5 scenes, or a bootstrap interval over 6, is a number a reader takes at face
value although a different handful of scenes would move it a lot (with 5 scenes a ρ of 0.9 has
a two-sided p of 0.08). Such numbers are not hidden (the n is always reported beside them), but
they carry a warning wherever they are shown:

* Markdown tables (the per-table ``.md`` files and ``analysis.md``): ``0.9 ⚠`` and a legend line
  under the table;
* LaTeX tables: ``0.9$^{\\dagger}$`` and the legend in the caption;
* the console (``visphy analyse``): the marked cells of the Spearman matrices, and one warning
  line per table with such numbers;
* ``analysis.json``: a ``small_sample`` flag per flagged row (its columns and n) under each
  table, and the threshold and counts at the top level.

What is flagged (`marks`): in ``spearman`` (long form) ρ and p where n < `MIN_SCENES`; in each
``spearman_<metric>`` matrix the cells of such pairs; in ``spearman_mean`` the mean ρ when any
pair it averages has n < `MIN_SCENES`; in ``bootstrap`` the difference, its interval, p and the
verdict where ``n common`` < `MIN_SCENES`; in ``judges`` both coefficients and their p where the
pooled n < `MIN_SCENES`. Values that are missing (NaN: fewer than 3 points or a constant side)
show as a dash and are not flagged. The CSV files keep the plain numbers (with their n).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

#: Fewer common scenes than this: the number is shown with a warning.
MIN_SCENES = 10
MARK = "⚠"
LATEX_MARK = r"$^{\dagger}$"
LEGEND = (f"{MARK} computed over fewer than {MIN_SCENES} common scenes: too few to rely on "
          "(n is given beside it).")
LATEX_LEGEND = (f"{LATEX_MARK} computed over fewer than {MIN_SCENES} common scenes: too few "
                "to rely on.")

#: The statistic columns of each table that rest on its n column.
_FLAGGED = {
    "spearman": ("n", ("ρ", "p")),
    "bootstrap": ("n common", ("A − B", "CI low", "CI high", "p", "better")),
    "judges": ("n", ("pearson r", "pearson p", "spearman ρ", "spearman p")),
}


def small(n) -> bool:
    """Whether a number computed over ``n`` scenes (or items) needs the warning."""
    try:
        n = float(n)
    except (TypeError, ValueError):
        return False
    return math.isfinite(n) and 0 < n < MIN_SCENES


def _shown(value) -> bool:
    """A value that is displayed as a number or a verdict (not a dash)."""
    if value is None:
        return False
    if isinstance(value, str):
        return bool(value)
    try:
        return not math.isnan(float(value))
    except (TypeError, ValueError):
        return True


def _row_marks(table: pd.DataFrame, n_col: str, cols: tuple[str, ...]) -> pd.DataFrame:
    mask = pd.DataFrame(False, index=table.index, columns=table.columns)
    if n_col not in table.columns:
        return mask
    for idx, row in table.iterrows():
        if small(row[n_col]):
            for c in cols:
                if c in table.columns and _shown(row[c]):
                    mask.loc[idx, c] = True
    return mask


def _matrix_marks(matrix: pd.DataFrame, long: pd.DataFrame, metric: str) -> pd.DataFrame:
    mask = pd.DataFrame(False, index=matrix.index, columns=matrix.columns)
    ns = {}
    for rec in long[long["metric"] == metric].to_dict("records"):
        ns[(rec["A"], rec["B"])] = ns[(rec["B"], rec["A"])] = rec["n"]
    for idx, row in matrix.iterrows():
        a = row["run"]
        for b in matrix.columns:
            if b != "run" and a != b and small(ns.get((a, b))) and _shown(row[b]):
                mask.loc[idx, b] = True
    return mask


def _mean_marks(means: pd.DataFrame, long: pd.DataFrame) -> pd.DataFrame:
    mask = pd.DataFrame(False, index=means.index, columns=means.columns)
    for idx, row in means.iterrows():
        pairs = long[(long["metric"] == row["metric"])
                     & np.isfinite(long["ρ"].to_numpy(np.float64))]
        if any(small(n) for n in pairs["n"]) and _shown(row["mean ρ"]):
            mask.loc[idx, "mean ρ"] = True
    return mask


def marks(tables: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    """Per table with small-sample numbers, a boolean mask of its cells (same index and
    columns) that need the warning. Tables without any are left out."""
    out: dict[str, pd.DataFrame] = {}
    long = tables.get("spearman")
    for name, table in tables.items():
        if name in _FLAGGED:
            mask = _row_marks(table, *_FLAGGED[name])
        elif name == "spearman_mean" and long is not None:
            mask = _mean_marks(table, long)
        elif name.startswith("spearman_") and long is not None and "run" in table.columns:
            mask = _matrix_marks(table, long, name[len("spearman_"):])
        else:
            continue
        if mask.to_numpy().any():
            out[name] = mask
    return out


def flags(table: pd.DataFrame, mask: pd.DataFrame, name: str) -> list[dict]:
    """The JSON flags of one table: per flagged row its position, the flagged columns and the n
    behind them."""
    n_col = _FLAGGED.get(name, (None,))[0]
    out = []
    for pos, (idx, row) in enumerate(mask.iterrows()):
        cols = [str(c) for c in mask.columns if row[c]]
        if not cols:
            continue
        flag = {"row": pos, "columns": cols, "small_sample": True}
        if n_col and n_col in table.columns:
            flag["n"] = int(table.loc[idx, n_col])
        if "metric" in table.columns:
            flag["metric"] = str(table.loc[idx, "metric"])
        if "run" in table.columns:
            flag["run"] = str(table.loc[idx, "run"])
        out.append(flag)
    return out


def console_warning(name: str, mask: pd.DataFrame) -> str:
    """One line for the console about a table with flagged numbers."""
    rows = int(mask.to_numpy().any(axis=1).sum())
    return (f"{MARK} {name}: {rows} row(s) computed over fewer than {MIN_SCENES} common scenes "
            f"(marked {MARK} in {name}.md and analysis.md): too few to rely on")
