"""The analysis on a terminal: the leaderboard, and one table of the Spearman correlations when
runs are compared (a row per metric, a column per pair of runs, the mean off-diagonal ρ last),
so a study's outcome is readable without opening a file. Numbers over fewer than
`small_sample.MIN_SCENES` common scenes are shown with ``⚠`` beside them, and every table that
has such numbers (the bootstrap's included) gets a warning line. A number is never cut: its
column is as wide as its widest cell, and the labels fold instead. A table wider than the
console is split over several, each with the labels first (`fitting_tables`)."""

from __future__ import annotations

import pandas as pd

from visphy_core.analysis import small_sample
from visphy_core.analysis.export import _marked, fmt
from visphy_core.infra.progress import output_columns

#: the console's width when stdout is no terminal and ``COLUMNS`` is unset
LOG_WIDTH = 200

#: the widest a label column gets before its labels fold onto more lines
LABEL_WIDTH = 30


def fitting_tables(df: pd.DataFrame, marks: pd.DataFrame | None, width: int) -> list:
    """``df`` as rich tables that each fit in ``width`` columns, the way pandas prints a wide
    frame: the first column (the labels) in every table, the other columns split, in order,
    over as many tables as it takes. One table when it fits; a column wider than the console
    on its own still gets a table of its own (its numbers whole, its labels folded)."""
    from rich.cells import cell_len

    cells = _cells(df, marks)
    label = _label_width(width)
    natural = []
    for i, col in enumerate(df.columns):
        widest = max([cell_len(str(col)), *(cell_len(r[i]) for r in cells)])
        natural.append(widest if _numeric(df[col]) else min(widest, label))
    if not natural:
        return [_table(df, cells, [], label)]
    first, rest = natural[0] + 3, list(range(1, len(df.columns)))  # 3: padding and a rule
    groups: list[list[int]] = [[]]
    used = 1 + first
    for i in rest:
        need = natural[i] + 3
        if groups[-1] and used + need > width:
            groups.append([])
            used = 1 + first
        groups[-1].append(i)
        used += need
    return [_table(df, cells, [0, *group], label) for group in groups]


def _label_width(width: int) -> int:
    return min(LABEL_WIDTH, max(12, width // 3))


def _numeric(series: pd.Series) -> bool:
    return pd.api.types.is_numeric_dtype(series) and not pd.api.types.is_bool_dtype(series)


def _cells(df: pd.DataFrame, marks: pd.DataFrame | None) -> list[list[str]]:
    return [[fmt(v) + (f" {small_sample.MARK}" if f else "") for v, f in zip(row, flags)]
            for row, flags in zip(df.itertuples(index=False), _marked(marks, df))]


def _table(df: pd.DataFrame, cells: list[list[str]], columns, label: int):
    from rich.cells import cell_len
    from rich.table import Table

    table = Table()
    for i in columns:
        col = df.columns[i]
        widest = max((cell_len(r[i]) for r in cells), default=0)
        if _numeric(df[col]):
            table.add_column(str(col), justify="right", no_wrap=True, min_width=widest,
                             overflow="fold")
        else:  # a label: whole up to ``label`` characters, folded beyond
            table.add_column(str(col), justify="left", overflow="fold",
                             min_width=min(widest, label) if i == 0 else None,
                             max_width=label)
    for row in cells:
        table.add_row(*(row[i] for i in columns))
    return table


def _print_fitting(console, df: pd.DataFrame, marks: pd.DataFrame | None = None) -> None:
    for table in fitting_tables(df, marks, console.width):
        console.print(table, crop=False)


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
    _print_fitting(console, tables["leaderboard"])
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
        _print_fitting(console, table, table_marks)
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
