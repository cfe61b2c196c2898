"""Reading and writing a run's rows (``results.jsonl``, ``results.parquet``).

The JSON lines are the record of a run as it goes: a row is appended (and fsynced) as each
scene finishes, so a killed run leaves every finished row and at most one half-written line.
Readers take the first row of each scene (a resumed run keeps the rows it finds, the first of
each) and count the lines they could not read. The Parquet file holds the same rows, written
when the run closes.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

from visphy_core.infra.files import atomic_write
from visphy_core.results.layout import RESULTS_JSONL, RESULTS_PARQUET
from visphy_core.results.row import SceneResult


def jsonl_line(result: SceneResult) -> str:
    """A row as one line of ``results.jsonl`` (newline included)."""
    return json.dumps(result.row(), default=str) + "\n"


def parse_line(line: str) -> SceneResult | None:
    """The row a line of ``results.jsonl`` holds; None for a line that is not a row (the
    half-written last line of a killed run)."""
    try:
        row = json.loads(line)
        if not isinstance(row, dict) or not isinstance(row.get("scene_id"), str):
            raise ValueError("not a row")
        return SceneResult.from_row(row)
    except (ValueError, TypeError, KeyError):
        return None


def parse_lines(text: str) -> tuple[list[SceneResult], int]:
    """The rows in the text of a ``results.jsonl``, first per scene, and the number of lines
    that were not a row (blank lines aside)."""
    rows: dict[str, SceneResult] = {}
    skipped = 0
    for line in text.splitlines():
        if not line.strip():
            continue
        result = parse_line(line)
        if result is None:
            skipped += 1
            continue
        rows.setdefault(result.scene_id, result)
    return list(rows.values()), skipped


def read_jsonl(path: Path) -> tuple[list[SceneResult], int]:
    """`parse_lines` of the file at ``path`` (bytes that are not UTF-8 replaced)."""
    return parse_lines(Path(path).read_bytes().decode("utf-8", errors="replace"))


def read_parquet(path: Path) -> list[SceneResult]:
    import pandas as pd

    rows = []  # a missing value is None, as in the lines (Parquet gives NaN for a float column)
    for record in pd.read_parquet(path).to_dict(orient="records"):
        rows.append({k: (None if isinstance(v, float) and math.isnan(v) else v)
                     for k, v in record.items()})
    seen: dict[str, SceneResult] = {}  # the same first-per-scene rule as the lines
    for row in rows:
        if isinstance(row.get("scene_id"), str) and row["scene_id"] not in seen:
            seen[row["scene_id"]] = SceneResult.from_row(row)
    return list(seen.values())


def read_results(run_dir: Path) -> tuple[list[SceneResult], int]:
    """A run's rows: ``results.jsonl`` (complete as soon as each scene is), else
    ``results.parquet``; with the number of lines that could not be read."""
    jsonl, parquet = Path(run_dir) / RESULTS_JSONL, Path(run_dir) / RESULTS_PARQUET
    if jsonl.is_file():
        return read_jsonl(jsonl)
    if parquet.is_file():
        return read_parquet(parquet), 0
    return [], 0


def parquet_bytes(results: list[SceneResult]) -> bytes:
    import pandas as pd

    buffer = io.BytesIO()
    pd.DataFrame([r.row() for r in results]).to_parquet(buffer, index=False)
    return buffer.getvalue()


def write_results(run_dir: Path, results: list[SceneResult], *, jsonl: bool = True) -> None:
    """``results.parquet`` (and, with ``jsonl``, ``results.jsonl``) holding ``results`` in
    order, each written atomically (a run that streamed its lines writes only the Parquet)."""
    if jsonl:
        atomic_write(Path(run_dir) / RESULTS_JSONL, "".join(jsonl_line(r) for r in results),
                     fsync=True)
    atomic_write(Path(run_dir) / RESULTS_PARQUET, parquet_bytes(results))
