"""A run's scores as one tidy table: one row per (scene, score column), the way pandas and polars
users reshape them.

A run's own table (``results.parquet``) is wide: one row per scene, one ``score_<column>`` per
metric and pairing (`visphy_core.results.columns`). `tidy_scores` melts it and spells each
column name out as four fields, so a groupby needs no string parsing:

* ``kind``: ``metric``, ``alignment`` (an alignment's own offset or error, ``align.*``),
  ``judge`` (``judge_*``) or ``headline`` (the run's headline score, ``physics_score``);
* ``metric``: the metric, alignment quantity, judge key or headline name;
* ``pairing``: ``visphy`` (frame by frame, unaligned), ``aligned`` (after the best time
  offset) or ``paper`` (the paper protocol); empty for judges;
* ``track``: ``program`` (the model's program) or ``spec`` (its stated physics replayed);
  ``normalised``: the variance-normalised value (0 = the still clip, 1 = the twin).

`score_column` is the exact inverse (`decompose_column` ∘ `score_column` is the identity over
every column a run writes), and the raw name stays in the ``column`` field. Every scene of the
run has a row for every column any scene has: a value the scene lacks is null, with the reason
in ``unavailable`` (the row's own reason, else ``no clip (<failure class>)`` for a scene with
no clip), so counting non-null values over the scenes gives the run's honest denominators.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import TYPE_CHECKING

# ScoreColumn, decompose_column and score_column are this module's API too (docs/results/export.md)
from visphy_core.results.columns import (  # noqa: F401
    ScoreColumn,
    column_direction,
    decompose_column,
    score_column,
)
from visphy_core.results.load import RunData, load_run

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

KINDS = ("metric", "alignment", "judge", "headline")
PAIRINGS = ("visphy", "aligned", "paper")
TRACKS = ("program", "spec")
#: The tidy table's columns, in order: per run, per scene, per value.
RUN_FIELDS = ("run", "run_status", "model", "engine", "dataset", "split")
SCENE_FIELDS = ("scene_id", "dim", "difficulty", "template", "model_success",
                "system_success", "fallback", "failure_class")
VALUE_FIELDS = ("column", "kind", "metric", "pairing", "track", "normalised", "direction",
                "value", "unavailable")
FIELDS = RUN_FIELDS + SCENE_FIELDS + VALUE_FIELDS

_TEMPLATE = (re.compile(r"vpb\d+-s\d+-(?:2d|3d)-(t\d+)-v\d+"),  # generated: the template
             re.compile(r"task(\d{5})_\d{3}"),                  # published 2D
             re.compile(r"\d+_(tmpl_\d+)"))                     # published 3D


def template_of(scene_id: str) -> str | None:
    """The template a scene id names: ``vpb3-s0-2d-t001-v00`` → ``t001``, ``task10063_000`` →
    ``10063``, ``14_tmpl_14`` → ``tmpl_14``; None for any other id."""
    for pattern in _TEMPLATE:
        match = pattern.fullmatch(scene_id)
        if match:
            return match.group(1)
    return None


def _ordered_columns(run: RunData) -> list[str]:
    seen: dict[str, None] = {}
    for result in run.results:
        for name in (*result.scores, *result.unavailable):
            seen.setdefault(name, None)
    return list(seen)


def _missing_reason(result, column: str) -> str:
    if column in result.unavailable:
        return str(result.unavailable[column])
    if not result.system_success:
        return f"no clip ({result.failure_class or 'failed'})"
    return "not computed for this scene"


def tidy_scores(run: RunData | str | Path) -> "pd.DataFrame":
    """The run's scores in long form, columns `FIELDS` (a run directory is read with
    `visphy_core.results.load.load_run`: an unfinished run gives the rows it has)."""
    import pandas as pd

    if not isinstance(run, RunData):
        run = load_run(run)
    headline = (run.summary.get("headline") or {}).get("metric")
    base = {name: str(info.get("direction"))
            for name, info in (run.summary.get("metric_info") or {}).items()
            if isinstance(info, dict)}
    run_values = (run.name, run.status, run.model, run.engine,
                  run.cfg("dataset.name") or run.summary.get("dataset"),
                  run.cfg("dataset.split"))
    columns = _ordered_columns(run)
    spelt = {c: decompose_column(c, headline) for c in columns}
    records = []
    for result in run.results:
        scene = (result.scene_id, result.dim, result.difficulty, template_of(result.scene_id),
                 bool(result.model_success), bool(result.system_success), bool(result.fallback),
                 result.failure_class)
        for column in columns:
            value = result.scores.get(column)
            if isinstance(value, float) and math.isnan(value):
                value = None
            why = None if value is not None else _missing_reason(result, column)
            s = spelt[column]
            records.append((*run_values, *scene, column, s.kind, s.metric, s.pairing, s.track,
                            s.normalised, column_direction(column, base),
                            None if value is None else float(value), why))
    frame = pd.DataFrame.from_records(records, columns=list(FIELDS))
    frame["value"] = frame["value"].astype("float64")
    for name in ("model_success", "system_success", "fallback", "normalised"):
        frame[name] = frame[name].astype("bool")
    return frame
