"""Reference rows: numbers the user adds from a file (published results, another lab's runs).

A reference row is never measured here, so it is shown in its own table, marked with its
source, and never enters a tie group or a rank. The file is YAML (``.yaml``/``.yml``), JSON
(a list of rows, or ``{"rows": [...]}``) or CSV with a header; each row has

* ``model`` and ``source`` (where the number comes from: a paper, a URL, a note) — required;
* optional ``engine``, ``dataset``, ``date``, ``note``;
* ``physics_score`` (or ``score``) with optional ``ci_low`` / ``ci_high`` and ``n``, and any
  other numeric column (another metric's published mean), shown as given.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from visphy_core.infra.errors import UserError

TEXT_KEYS = ("model", "engine", "dataset", "source", "date", "note")


@dataclass
class Reference:
    model: str
    source: str
    engine: str = ""
    dataset: str = ""
    date: str = ""
    note: str = ""
    score: float | None = None
    ci: tuple[float, float] | None = None
    n: int | None = None
    others: dict[str, float] = field(default_factory=dict)


def _number(value: Any, where: str, key: str) -> float | None:
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise UserError(f"{where}: {key}={value!r} is not a number") from None
    if not math.isfinite(v):
        raise UserError(f"{where}: {key}={value!r} is not a finite number")
    return v


def _rows(path: Path) -> list[Any]:
    text = path.read_text(encoding="utf-8", errors="replace")
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            return list(csv.DictReader(text.splitlines()))
        if suffix == ".json":
            data = json.loads(text)
        elif suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            raise UserError(f"{path}: a reference file is .yaml, .yml, .json or .csv")
    except (ValueError, csv.Error) as exc:
        raise UserError(f"{path}: cannot read it ({type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    except Exception as exc:  # noqa: BLE001 - yaml's errors: a bad file, said in one line
        if type(exc).__module__.startswith("yaml"):
            raise UserError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
        raise
    if isinstance(data, dict) and isinstance(data.get("rows"), list):
        data = data["rows"]
    if not isinstance(data, list):
        raise UserError(f"{path}: expected a list of rows (or {{rows: [...]}})")
    return data


def read_references(path: str | Path) -> list[Reference]:
    """The rows of a reference file (`UserError` naming the file and row when one is bad)."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise UserError(f"{path}: no such reference file")
    out = []
    for i, row in enumerate(_rows(path), start=1):
        where = f"{path} row {i}"
        if not isinstance(row, dict):
            raise UserError(f"{where}: a row is a mapping of column to value")
        row = {str(k).strip(): v for k, v in row.items() if k is not None}
        missing = [k for k in ("model", "source") if not str(row.get(k) or "").strip()]
        if missing:
            raise UserError(f"{where}: missing {' and '.join(missing)} (every reference row "
                            "names its model and where its number comes from)")
        score = _number(row.get("physics_score", row.get("score")), where, "physics_score")
        lo, hi = _number(row.get("ci_low"), where, "ci_low"), _number(row.get("ci_high"),
                                                                      where, "ci_high")
        n = _number(row.get("n"), where, "n")
        others = {}
        for key, value in row.items():
            if key in TEXT_KEYS or key in ("physics_score", "score", "ci_low", "ci_high", "n"):
                continue
            number = _number(value, where, key)
            if number is not None:
                others[key] = number
        out.append(Reference(**{k: str(row.get(k) or "").strip() for k in TEXT_KEYS},
                             score=score, ci=(lo, hi) if lo is not None and hi is not None
                             else None, n=int(n) if n is not None else None, others=others))
    return out
