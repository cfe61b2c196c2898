"""The headline split by what a scene is: difficulty, template, a dataset label, 2D/3D; and a
cross-engine study as a model × engine matrix.

Every cell is the mean headline (the rows' own view, `visphy_core.leaderboard.entries`) over
the row's scenes in that group, with its count, so a cell over two scenes reads as such.
Templates come from the scene id (``vpb3-s0-2d-t001-v00`` → ``t001``); labels from a file the
user gives (`read_labels`: a scene id and a label per row, e.g. the benchmark's
``metadata.jsonl`` with its ``family``).
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from visphy_core.analysis.breakdown import DIFFICULTY_ORDER
from visphy_core.infra.errors import UserError
from visphy_core.leaderboard.entries import Entry, template_of

LABEL_KEYS = ("label", "family", "category")


@dataclass
class Breakdown:
    """Rows × groups: ``cells[slug][group] = (mean, n)``."""

    key: str
    title: str
    groups: list[str]
    cells: dict[str, dict[str, tuple[float, int]]]


def scene_groups(entry: Entry, key: str, labels: dict[str, str] | None = None
                 ) -> dict[str, str]:
    """Scene id → its group under ``key`` (``difficulty``, ``dim``, ``template``, ``label``)."""
    df = entry.run.table
    if df.empty:
        return {}
    ids = df["scene_id"].astype(str)
    if key == "template":
        return {s: t for s in ids if (t := template_of(s))}
    if key == "label":
        return {s: labels[s] for s in ids if labels and s in labels}
    if key not in df.columns:
        return {}
    values = df[key].where(df[key].notna(), None)
    return {s: (str(v).upper() if key == "dim" else str(v))
            for s, v in zip(ids, values) if v is not None}


def _order(key: str, groups: set[str]) -> list[str]:
    if key == "difficulty":
        return sorted(groups, key=lambda g: (DIFFICULTY_ORDER.index(g)
                                             if g in DIFFICULTY_ORDER else 9, g))
    return sorted(groups)


def breakdown(entries: list[Entry], key: str, title: str,
              labels: dict[str, str] | None = None) -> Breakdown | None:
    """The headline per row and group; None when no row has two groups' worth of data."""
    cells: dict[str, dict[str, tuple[float, int]]] = {}
    seen: set[str] = set()
    for e in entries:
        groups = scene_groups(e, key, labels)
        frame = pd.DataFrame({"value": e.values,
                              "group": [groups.get(str(s)) for s in e.values.index]})
        frame = frame.dropna(subset=["group"])
        row = {g: (float(sub["value"].mean()), int(len(sub)))
               for g, sub in frame.groupby("group")}
        seen |= set(row)
        cells[e.slug] = row
    if len(seen) < 2 and key != "label":
        return None
    if not seen:
        return None
    return Breakdown(key, title, _order(key, seen), cells)


def engine_matrix(entries: list[Entry]) -> dict[str, tuple[list[str], list[str],
                                                           dict[tuple[str, str], list[Entry]]]]:
    """Per dataset with more than one engine: its models, its engines and the rows in each
    model × engine cell."""
    out = {}
    for dataset in sorted({e.dataset for e in entries}):
        members = [e for e in entries if e.dataset == dataset and e.mean is not None]
        engines = sorted({e.engine for e in members})
        if len(engines) < 2:
            continue
        models = sorted({e.model for e in members})
        cells: dict[tuple[str, str], list[Entry]] = {}
        for e in members:
            cells.setdefault((e.model, e.engine), []).append(e)
        out[dataset] = (models, engines, cells)
    return out


def read_labels(path: str | Path) -> dict[str, str]:
    """Scene id → label from a CSV, JSON (a mapping, or a list of rows) or JSON Lines file; a
    row's label is its ``label``, ``family`` or ``category``."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise UserError(f"{path}: no such labels file")
    text = path.read_text(encoding="utf-8", errors="replace")
    try:
        if path.suffix.lower() == ".csv":
            rows = list(csv.DictReader(text.splitlines()))
        elif path.suffix.lower() == ".jsonl":
            rows = [json.loads(line) for line in text.splitlines() if line.strip()]
        else:
            data = json.loads(text)
            rows = ([{"scene_id": k, "label": v} for k, v in data.items()]
                    if isinstance(data, dict) else data)
    except (ValueError, csv.Error) as exc:
        raise UserError(f"{path}: cannot read it ({type(exc).__name__})") from None
    out = {}
    for row in rows if isinstance(rows, list) else []:
        if not isinstance(row, dict) or not row.get("scene_id"):
            continue
        value = next((row[k] for k in LABEL_KEYS if row.get(k) not in (None, "")), None)
        if value is not None:
            out[str(row["scene_id"])] = str(value)
    if not out:
        raise UserError(f"{path}: no row with a scene_id and one of {', '.join(LABEL_KEYS)}")
    return out
