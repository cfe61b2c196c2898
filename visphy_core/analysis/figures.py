"""Figures for a paper: per-scene boxplots per metric (one box per run) and a radar chart of the
runs over the headline metrics, each written as PNG and SVG (matplotlib, Agg backend: no
display needed).

The radar scales each metric to `RADAR_FLOOR`..1 across the runs compared, with direction
respected: the best run on a metric sits at 1 and the worst at `RADAR_FLOOR` (0.2) whether higher
or lower is better (a metric on which all runs tie sits at 1 for all). The floor keeps the worst
run a visible polygon (scaled to 0 it would collapse to the centre); each run also has its own
marker and line style, and the legend names them. The scaled values are returned as a table as
well, so the figure can be checked and re-drawn. SVG output is deterministic (no date, fixed id
salt).
"""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd

from visphy_core.analysis.column_views import MODEL_SUCCESS, direction, header, scene_values
from visphy_core.results.load import RunData

FORMATS = ("png", "svg")
#: Where the worst run on a metric sits on the radar (the best at 1).
RADAR_FLOOR = 0.2
#: Each run's marker and line style on the radar (cycled).
RADAR_STYLES = (("o", "-"), ("s", "--"), ("^", "-."), ("D", ":"), ("v", "-"), ("P", "--"))


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "visphy"
    return plt


def safe_name(text: str) -> str:
    """A file-name-safe version of a table or metric name."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "x"


def save(fig, out_dir: Path, name: str, tight_box: bool = False) -> list[Path]:
    """``fig`` as ``<name>.png`` and ``<name>.svg`` under ``out_dir``. The layout is fitted
    once (``tight_layout``; ``tight_box`` crops to every artist instead, for legends outside
    the axes, at the cost of a second drawing per file)."""
    plt = _pyplot()
    if not tight_box:
        fig.tight_layout()
    paths = []
    for ext in FORMATS:
        path = out_dir / f"{safe_name(name)}.{ext}"
        meta = {"Date": None} if ext == "svg" else {"Software": None}
        fig.savefig(path, dpi=150, bbox_inches="tight" if tight_box else None, metadata=meta)
        paths.append(path)
    plt.close(fig)
    return paths


def _wrapped(label: str, width: int = 18) -> str:
    """A run label on lines of about ``width`` characters, broken at spaces (never cut: the
    end of a label is what tells two runs apart)."""
    return textwrap.fill(label, width, break_long_words=False, break_on_hyphens=False)


def boxplot(runs: list[RunData], labels: list[str], column: str, out_dir: Path,
            view: str = MODEL_SUCCESS) -> list[Path]:
    """One box per run of the column's per-scene values (n under each box); [] when no run has
    a value."""
    data = [scene_values(r, column, view).to_numpy(np.float64) for r in runs]
    if not any(len(d) for d in data):
        return []
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(max(4.0, 1.3 * len(runs) + 1.5), 3.8))
    ax.boxplot([d if len(d) else [np.nan] for d in data], showmeans=True)
    ax.set_xticks(range(1, len(runs) + 1),
                  [f"{_wrapped(lab)}\nn={len(d)}" for lab, d in zip(labels, data)], fontsize=7)
    ax.set_ylabel(header(runs, column))
    ax.set_title(f"{header(runs, column)} per scene ({view.replace('_', ' ')})", fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    return save(fig, out_dir, f"boxplot_{column}")


def radar_table(runs: list[RunData], labels: list[str], columns: list[str],
                view: str = MODEL_SUCCESS) -> pd.DataFrame:
    """Runs × metrics, each metric's run means scaled to `RADAR_FLOOR`..1 across runs (1 = the
    best, `RADAR_FLOOR` the worst); metrics without a direction or with no value for some run
    are left out."""
    means = {}
    for col in columns:
        way = direction(runs, col)
        vals = [scene_values(r, col, view) for r in runs]
        if way is None or not all(len(v) for v in vals):
            continue
        m = np.array([v.mean() for v in vals], dtype=np.float64)
        span = m.max() - m.min()
        if span == 0:
            means[header(runs, col)] = np.ones_like(m)
            continue
        good = (m - m.min()) / span if way == "higher" else (m.max() - m) / span
        means[header(runs, col)] = RADAR_FLOOR + (1.0 - RADAR_FLOOR) * good
    table = pd.DataFrame(means)
    table.insert(0, "run", labels)
    return table


def radar(table: pd.DataFrame, out_dir: Path) -> list[Path]:
    """The radar chart of `radar_table` (at least 3 metrics and 2 runs, else [])."""
    metrics = [c for c in table.columns if c != "run"]
    if len(metrics) < 3 or len(table) < 2:
        return []
    plt = _pyplot()
    angles = np.linspace(0, 2 * np.pi, len(metrics), endpoint=False)
    closed = np.concatenate([angles, angles[:1]])
    fig, ax = plt.subplots(figsize=(6.0, 6.0), subplot_kw={"projection": "polar"})
    for i, (_, row) in enumerate(table.iterrows()):
        values = row[metrics].to_numpy(np.float64)
        marker, style = RADAR_STYLES[i % len(RADAR_STYLES)]
        ring = np.concatenate([values, values[:1]])
        lines = ax.plot(closed, ring, linewidth=1.8, linestyle=style, marker=marker,
                        markersize=6, label=_wrapped(str(row["run"]), 28), zorder=3 + i)
        ax.fill(closed, ring, alpha=0.10, color=lines[0].get_color())
    ax.set_xticks(angles, [_wrapped(m, 14) for m in metrics], fontsize=8)
    ax.tick_params(axis="x", pad=12)
    ax.set_ylim(0, 1.05)
    ax.set_yticks([RADAR_FLOOR, 0.6, 1.0], ["worst", "", "best"], fontsize=7, color="0.35")
    ax.set_rlabel_position(90 / len(metrics))
    ax.set_title(f"runs over the headline metrics (each metric: the worst run at "
                 f"{RADAR_FLOOR:g}, the best at 1)", fontsize=10, pad=18)
    ax.legend(loc="upper left", bbox_to_anchor=(1.08, 1.0), fontsize=8, frameon=False)
    return save(fig, out_dir, "radar", tight_box=True)
