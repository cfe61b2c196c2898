"""The analysis on a terminal: the leaderboard, and one table of the Spearman correlations when
runs are compared (a row per metric, a column per pair of runs, the mean off-diagonal ρ last),
so a study's outcome is readable without opening a file. Numbers over fewer than
`small_sample.MIN_SCENES` common scenes are shown with ``⚠`` beside them, and every table that
has such numbers (the bootstrap's included) gets a warning line. A number is never cut: its
column is as wide as its widest cell, and the labels fold instead."""

from __future__ import annotations


import pandas as pd

from visphy_core.analysis import small_sample
from visphy_core.analysis.export import _marked, fmt
from visphy_core.infra.progress import output_columns

#: the console's width when stdout is no terminal and ``COLUMNS`` is unset
LOG_WIDTH = 200


def rich_table(df: pd.DataFrame, marks: pd.DataFrame | None = None):
    """``df`` as a rich table: numeric columns right-justified and never narrower than their
    widest cell (a number is not cut), the other columns folding onto more lines."""
    from rich.table import Table

    cells = [[fmt(v) + (f" {small_sample.MARK}" if f else "") for v, f in zip(row, flags)]
             for row, flags in zip(df.itertuples(index=False), _marked(marks, df))]
    table = Table()
    for i, col in enumerate(df.columns):
        numeric = pd.api.types.is_numeric_dtype(df[col]) and not pd.api.types.is_bool_dtype(df[col])
        widest = max((len(r[i]) for r in cells), default=0)
        if numeric:
            table.add_column(str(col), justify="right", no_wrap=True, min_width=widest,
                             overflow="fold")
        else:  # a label: whole up to 20 characters, folded beyond
            table.add_column(str(col), justify="left", overflow="fold",
                             min_width=min(widest, 20) if i == 0 else None)
    for row in cells:
        table.add_row(*row)
    return table


def spearman_table(long: pd.DataFrame, means: pd.DataFrame | None,
                   long_marks: pd.DataFrame | None, mean_marks: pd.DataFrame | None
                   ) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """Every metric's ρ for every pair of runs in one table: a row per metric, a column per
    pair (``1–2``: runs numbered as in the returned legend lines), then the mean off-diagonal
    ρ. Returns the table, its marks (small samples) and the legend: the runs, and each pair's
    common scenes."""
    runs: list[str] = []
    for a, b in zip(long["A"], long["B"]):
        for label in (a, b):
            if label not in runs:
                runs.append(label)
    number = {label: i + 1 for i, label in enumerate(runs)}
    pair_of = {(a, b): f"ρ {number[a]}–{number[b]}" for a, b in zip(long["A"], long["B"])}
    pairs = list(dict.fromkeys(pair_of.values()))
    metrics = list(dict.fromkeys(long["metric"]))
    mean_of = dict(zip(means["metric"], means["mean ρ"])) if means is not None else {}
    mean_flag = (dict(zip(means["metric"], mean_marks["mean ρ"]))
                 if means is not None and mean_marks is not None else {})
    table = pd.DataFrame({"metric": metrics, **{p: [float("nan")] * len(metrics) for p in pairs},
                          "mean ρ": [mean_of.get(m, float("nan")) for m in metrics]})
    marks = pd.DataFrame(False, index=table.index, columns=table.columns)
    ns: dict[str, list[int]] = {p: [] for p in pairs}
    flags = (long_marks["ρ"].tolist() if long_marks is not None and "ρ" in long_marks
             else [False] * len(long))
    for rec, flag in zip(long.to_dict("records"), flags):
        row, col = metrics.index(rec["metric"]), pair_of[(rec["A"], rec["B"])]
        table.loc[row, col] = rec["ρ"]
        marks.loc[row, col] = bool(flag)
        ns[col].append(int(rec["n"]))
    for i, m in enumerate(metrics):
        marks.loc[i, "mean ρ"] = bool(mean_flag.get(m, False))
    legend = ["runs: " + "; ".join(f"{number[r]} = {r}" for r in runs)]
    spans = []
    for p in pairs:
        lo, hi = min(ns[p], default=0), max(ns[p], default=0)
        spans.append(f"{p.removeprefix('ρ ')}: {lo}" + (f"–{hi}" if hi != lo else ""))
    legend.append("common scenes per pair: " + ", ".join(spans))
    return table, marks, legend


def _console():
    from rich.console import Console

    return Console(width=output_columns(LOG_WIDTH), highlight=False)


def print_study(outputs, out_dir=None, console=None) -> None:
    """Print the leaderboard, the one Spearman table (`spearman_table`), the small-sample
    warnings, then where the files are."""
    console = console or _console()
    tables = outputs.tables
    console.print("[bold]Leaderboard[/bold] (means over the model's own successes; n = scenes "
                  "in each mean)")
    console.print(rich_table(tables["leaderboard"]), crop=False)
    long = tables.get("spearman")
    marks = getattr(outputs, "marks", None) or {}
    if long is not None and len(long):
        table, table_marks, legend = spearman_table(long, tables.get("spearman_mean"),
                                                    marks.get("spearman"),
                                                    marks.get("spearman_mean"))
        console.print("[bold]Spearman ρ over scenes[/bold], per metric and pair of runs, "
                      "with the mean off-diagonal ρ (p-values in spearman.csv)")
        for line in legend:
            console.print(line, markup=False)
        console.print(rich_table(table, table_marks), crop=False)
        if table_marks.to_numpy().any():
            console.print(f"{small_sample.MARK} fewer than {small_sample.MIN_SCENES} common "
                          f"scenes behind the marked ρ: too few to rely on")
    for name, mask in marks.items():
        if not name.startswith("spearman"):
            console.print(small_sample.console_warning(name, mask))
    if out_dir is not None:
        console.print(f"analysis written to {out_dir} ({len(tables)} tables, "
                      f"{len(outputs.figures)} figures): analysis.md, analysis.json",
                      soft_wrap=True)
