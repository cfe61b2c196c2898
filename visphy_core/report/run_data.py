"""Read a run directory for a report, whatever state the run is in, without changing it.

A finished run has ``summary.json`` and ``results.parquet``; a run that was interrupted or
killed may have only ``results.jsonl`` (with a half-written last line) and ``manifest.json``.
The report needs the same view of both, so rows come from ``results.jsonl`` (parquet when the
lines are gone) and, when ``summary.json`` is missing, the summary's counts and means are
recomputed from the rows with the run's own rule (`visphy_core.execute.run.summarise`: means over
model successes, and over every scored scene with fallbacks). Nothing here writes to the run.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from visphy_core.infra import files
from visphy_core.infra.errors import UserError
from visphy_core.results.columns import SPEC_PREFIX, column_direction
from visphy_core.results.row import NOT_EVALUABLE, SceneResult

#: What a directory needs to be read as a run (any one of them).
RUN_MARKERS = ("manifest.json", "config.yaml", "results.jsonl", "summary.json")


@dataclass
class RunData:
    """Everything a run report shows, read once."""

    run_dir: Path
    config: dict[str, Any]
    manifest: dict[str, Any]
    summary: dict[str, Any]
    #: Where the summary came from: ``summary.json``, or recomputed (the run did not finish).
    summary_source: str
    results: list[SceneResult]
    #: Scenes the run selected that have no row (not reached, or abandoned when interrupted).
    pending: list[str] = field(default_factory=list)
    #: Lines of results.jsonl that could not be read (the half-written line of a killed run).
    skipped_lines: int = 0

    @property
    def name(self) -> str:
        return self.run_dir.name

    @property
    def status(self) -> str:
        return str(self.manifest.get("status") or self.summary.get("status") or "unknown")

    def cfg(self, dotted: str, default: Any = None) -> Any:
        """A value of the resolved config by dotted key (``dataset.split``)."""
        node: Any = self.config
        for part in dotted.split("."):
            if not isinstance(node, dict) or part not in node:
                return default
            node = node[part]
        return node


def is_run_dir(path: Path) -> bool:
    return path.is_dir() and any((path / marker).is_file() for marker in RUN_MARKERS)


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8", errors="replace"))
    except ValueError:
        return {}
    return data if isinstance(data, dict) else {}


def _read_config(path: Path) -> dict[str, Any]:
    if not path.is_file():
        return {}
    from omegaconf import OmegaConf

    try:
        data = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    except Exception:  # noqa: BLE001 - a damaged config leaves the report without it
        return {}
    return data if isinstance(data, dict) else {}


def _rows_from_jsonl(path: Path) -> tuple[list[dict], int]:
    rows, skipped = [], 0
    for line in path.read_bytes().decode("utf-8", errors="replace").splitlines():
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except ValueError:
            skipped += 1
            continue
        if isinstance(row, dict) and isinstance(row.get("scene_id"), str):
            rows.append(row)
        else:
            skipped += 1
    return rows, skipped


def _rows_from_parquet(path: Path) -> list[dict]:
    import pandas as pd

    frame = pd.read_parquet(path)
    rows = []
    for record in frame.to_dict(orient="records"):
        rows.append({k: (None if isinstance(v, float) and math.isnan(v)
                         and not k.startswith("score_") else v) for k, v in record.items()})
    return rows


def read_results(run_dir: Path) -> tuple[list[SceneResult], int]:
    """The run's rows, first row per scene wins (as a resumed run reads them), and the number
    of lines that could not be read."""
    jsonl, parquet = run_dir / "results.jsonl", run_dir / "results.parquet"
    if jsonl.is_file():
        raw, skipped = _rows_from_jsonl(jsonl)
    elif parquet.is_file():
        raw, skipped = _rows_from_parquet(parquet), 0
    else:
        raw, skipped = [], 0
    seen: dict[str, SceneResult] = {}
    for row in raw:
        if row["scene_id"] in seen:
            continue
        try:
            seen[row["scene_id"]] = SceneResult.from_row(row)
        except (TypeError, ValueError, KeyError):
            skipped += 1
    return list(seen.values()), skipped


def load_run(run_dir: Path) -> RunData:
    """Read ``run_dir``; `UserError` (one line) when it is not a run directory."""
    run_dir = Path(run_dir)
    if not is_run_dir(run_dir):
        what = "does not exist" if not run_dir.exists() else (
            "is not a directory" if not run_dir.is_dir() else
            f"is not a visphy run directory (none of {', '.join(RUN_MARKERS)})")
        raise UserError(f"{run_dir} {what}; pass a folder under <VISPHY_HOME>/runs/")
    files.refuse_tree(run_dir, "run directory")
    manifest = _read_json(run_dir / "manifest.json")
    results, skipped = read_results(run_dir)
    order = [str(s) for s in manifest.get("scenes") or []]
    position = {sid: i for i, sid in enumerate(order)}
    results.sort(key=lambda r: position.get(r.scene_id, len(position)))
    done = {r.scene_id for r in results}
    pending = [sid for sid in order if sid not in done]
    summary = _read_json(run_dir / "summary.json")
    if summary:
        source = "summary.json"
    else:
        summary = summarise_rows(results, manifest)
        source = ("recomputed from results.jsonl: the run has no summary.json (it was killed "
                  "or is still running)")
    return RunData(run_dir=run_dir, config=_read_config(run_dir / "config.yaml"),
                   manifest=manifest, summary=summary, summary_source=source, results=results,
                   pending=pending, skipped_lines=skipped)


# ------------------------------------------------------------------ a summary from rows


def summarise_rows(results: list[SceneResult], manifest: dict[str, Any]) -> dict[str, Any]:
    """The counts and means of `visphy_core.execute.run.summarise` for a run that never wrote its
    summary (directions from the manifest's metric list)."""
    base = {str(m.get("name")): str(m.get("direction", "higher"))
            for m in manifest.get("metrics") or [] if isinstance(m, dict)}
    ok = [r for r in results if r.model_success]
    scored = [r for r in results if r.system_success]
    evaluable = [r for r in results if r.failure_class not in NOT_EVALUABLE]
    failures: dict[str, dict[str, int]] = {"model": {}, "infra_or_data": {}}
    for r in results:
        if not r.model_success and r.failure_class:
            side = "infra_or_data" if r.failure_class in NOT_EVALUABLE else "model"
            failures[side][r.failure_class] = failures[side].get(r.failure_class, 0) + 1
    columns: list[str] = []
    for r in results:
        columns += [c for c in r.scores if c not in columns]
    metrics = {}
    for name in columns:
        def mean(rows: list[SceneResult]) -> tuple[float | None, int]:
            vals = [float(r.scores[name]) for r in rows if r.scores.get(name) is not None]
            return (sum(vals) / len(vals) if vals else None), len(vals)

        ok_mean, ok_n = mean(ok)
        all_mean, all_n = mean(evaluable if name.startswith(SPEC_PREFIX) else scored)
        reasons = sorted({r.unavailable[name] for r in results if name in r.unavailable})
        metrics[name] = {"direction": column_direction(name, base),
                         "mean_model_success": ok_mean, "n_model_success": ok_n,
                         "mean_with_fallbacks": all_mean, "n_with_fallbacks": all_n,
                         "unavailable": reasons[0] if reasons else None}
    n = len(results)
    flags: dict[str, int] = {}
    for r in results:
        for f in r.flags:
            flags[f] = flags.get(f, 0) + 1
    return {
        "n_scenes": n, "n_evaluable": len(evaluable),
        "model_success": len(ok), "model_success_rate": len(ok) / n if n else None,
        "model_success_rate_evaluable": len(ok) / len(evaluable) if evaluable else None,
        "system_success": len(scored), "system_success_rate": len(scored) / n if n else None,
        "fallbacks": sum(r.fallback for r in results),
        "repaired": sum(r.model_success and r.attempts > 1 for r in results),
        "failures": failures, "infra_retries": sum(r.infra_retries for r in results),
        "flags": flags, "metrics": metrics,
        "prompt_versions": sorted({r.prompt_version for r in results if r.prompt_version}),
        "spec": {"valid": sum(r.spec_valid is True for r in results),
                 "invalid": sum(r.spec_valid is False for r in results),
                 "absent": sum(r.spec_valid is None for r in results)},
    }
