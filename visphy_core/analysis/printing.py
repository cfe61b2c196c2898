"""The analysis on a terminal: the leaderboard, and a Spearman matrix per metric when runs are
compared (rich tables), so a study's outcome is readable without opening a file. Numbers over
fewer than `small_sample.MIN_SCENES` common scenes are shown with ``⚠`` beside them, and every
table that has such numbers (the bootstrap's included) gets a warning line."""

from __future__ import annotations

import math

import pandas as pd

from visphy_core.analysis import small_sample
from visphy_core.analysis.export import _marked, fmt


def rich_table(df: pd.DataFrame, marks: pd.DataFrame | None = None):
    from rich.table import Table

    table = Table()
    for col in df.columns:
        numeric = pd.api.types.is_numeric_dtype(df[col]) and not pd.api.types.is_bool_dtype(df[col])
        table.add_column(str(col), justify="right" if numeric else "left",
                         no_wrap=col == df.columns[0])
    for row, flags in zip(df.itertuples(index=False), _marked(marks, df)):
        table.add_row(*(fmt(v) + (f" {small_sample.MARK}" if f else "")
                        for v, f in zip(row, flags)))
    return table


def print_study(outputs, out_dir=None, console=None) -> None:
    """Print the leaderboard, each ``spearman_<metric>`` matrix with the mean off-diagonal ρ,
    then where the files are."""
    from rich.console import Console

    console = console or Console(width=200)
    tables = outputs.tables
    console.print("[bold]Leaderboard[/bold] (means over the model's own successes; n = scenes "
                  "in each mean)")
    console.print(rich_table(tables["leaderboard"]))
    long = tables.get("spearman")
    means = tables.get("spearman_mean")
    mean_of = dict(zip(means["metric"], means["mean ρ"])) if means is not None else {}
    marks = getattr(outputs, "marks", None) or {}
    mean_marks = marks.get("spearman_mean")
    mean_small = ({m for m, f in zip(means["metric"], mean_marks["mean ρ"]) if f}
                  if mean_marks is not None else set())
    for name, table in tables.items():
        if not name.startswith("spearman_") or name == "spearman_mean":
            continue
        metric = name[len("spearman_"):]
        rho = mean_of.get(metric, math.nan)
        ns = long.loc[long["metric"] == metric, "n"] if long is not None else pd.Series([])
        span = f"{ns.min()}–{ns.max()}" if len(ns) and ns.min() != ns.max() else \
            (str(ns.iloc[0]) if len(ns) else "0")
        warn = f" {small_sample.MARK}" if metric in mean_small else ""
        console.print(f"[bold]Spearman ρ over scenes: {metric}[/bold] (mean off-diagonal "
                      f"ρ = {fmt(rho)}{warn}; common scenes per pair: {span}; p-values in "
                      "spearman.csv)")
        console.print(rich_table(table, marks.get(name)))
        if name in marks:
            console.print(f"{small_sample.MARK} fewer than {small_sample.MIN_SCENES} common "
                          f"scenes behind the marked ρ: too few to rely on", soft_wrap=True)
    for name, mask in marks.items():
        if not name.startswith("spearman_"):
            console.print(small_sample.console_warning(name, mask), soft_wrap=True)
    if out_dir is not None:
        console.print(f"analysis written to {out_dir} ({len(tables)} tables, "
                      f"{len(outputs.figures)} figures): analysis.md, analysis.json")
