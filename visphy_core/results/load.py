"""A run directory as data, whatever state the run is in, read without changing it.

A finished run has ``summary.json`` and ``results.parquet``; a run that was interrupted or
killed may have only ``results.jsonl`` (with a half-written last line) and ``manifest.json``.
`load_run` gives the same view of both: rows from ``results.jsonl`` (Parquet when the lines are
gone, `visphy_core.results.rows`), and, when ``summary.json`` is missing, the summary's counts
and means recomputed from the rows with the run's own rule
(`visphy_core.results.summary.summarise_rows`). Reports, analyses, merges and re-scoring read
runs through it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from visphy_core.infra import files
from visphy_core.infra.errors import UserError
from visphy_core.results.layout import (
    COMPLETE,
    CONFIG,
    RESULTS_JSONL,
    RESULTS_PARQUET,
    RUN_MARKERS,
    SCENES,
    SUMMARY,
    is_run_dir,
)
from visphy_core.results.row import SceneResult
from visphy_core.results.run_dir import RunDir
from visphy_core.results.summary import summarise_rows

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd

#: The row fields an analysis reads, with the value a row without the field means.
ROW_DEFAULTS = {"scene_id": None, "dim": None, "difficulty": None, "model_success": False,
                "system_success": False, "fallback": False, "attempts": 0,
                "failure_class": None, "first_failure_class": None}


@dataclass
class RunData:
    """One run read once: its resolved config, manifest, summary and rows."""

    run_dir: Path
    config: dict[str, Any]
    manifest: dict[str, Any]
    summary: dict[str, Any]
    results: list[SceneResult]
    #: Where the summary came from: ``summary.json``, or recomputed (the run did not finish).
    summary_source: str = SUMMARY
    #: Scenes the run selected that have no row (not reached, or abandoned when interrupted).
    pending: list[str] = field(default_factory=list)
    #: Lines of results.jsonl that could not be read (the half-written line of a killed run).
    skipped_lines: int = 0
    #: Human ratings of the run's scenes, when an analysis read them
    #: (`visphy_core.analysis.human.read_ratings`).
    ratings: Any = None
    _label: str | None = field(default=None, repr=False)

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

    @property
    def model(self) -> str:
        return str(self.cfg("model.name") or self.summary.get("model") or "?")

    @property
    def engine(self) -> str:
        return str(self.cfg("engine.name") or self.summary.get("engine") or "?")

    @property
    def base_label(self) -> str:
        """``model/engine``."""
        return f"{self.model}/{self.engine}"

    @property
    def label(self) -> str:
        """The run's name in a comparison (set by `visphy_core.analysis.load.load_runs`), else
        ``model/engine``."""
        return self._label or self.base_label

    @cached_property
    def table(self) -> "pd.DataFrame":
        """The rows as a table, one row per scene, columns as in ``results.parquet`` (fields
        an older row lacks filled with `ROW_DEFAULTS`)."""
        import pandas as pd

        df = pd.DataFrame([r.row() for r in self.results])
        for column, default in ROW_DEFAULTS.items():
            if column not in df.columns:
                df[column] = default
        return df


def flatten(config: Any, prefix: str = "") -> dict[str, Any]:
    """A config (nested dicts) as dotted keys: ``{"dataset": {"split": "x"}}`` →
    ``{"dataset.split": "x"}``."""
    out: dict[str, Any] = {}
    if isinstance(config, dict):
        for key, value in config.items():
            out.update(flatten(value, f"{prefix}{key}."))
    else:
        out[prefix[:-1]] = config
    return out


def _or_empty(read: Callable[[], Any]) -> dict[str, Any]:
    """What ``read`` gives, as a dict; empty when the file is missing or damaged (a run being
    read as it is, whatever state it is in)."""
    try:
        data = read()
    except (OSError, ValueError):
        return {}
    except Exception:  # noqa: BLE001 - a damaged config (OmegaConf's own errors) reads as none
        return {}
    if hasattr(data, "_metadata"):  # a DictConfig
        from omegaconf import OmegaConf

        data = OmegaConf.to_container(data, resolve=False)
    return data if isinstance(data, dict) else {}


def load_run(run_dir: str | Path, *, finished: bool = False) -> RunData:
    """Read ``run_dir``; `UserError` (one line) when it is not a run directory, or, with
    ``finished``, when it has no readable ``summary.json`` or no rows."""
    run_dir = Path(run_dir).expanduser()
    if not is_run_dir(run_dir):
        what = "does not exist" if not run_dir.exists() else (
            "is not a directory" if not run_dir.is_dir() else
            f"is not a visphy run directory (none of {', '.join(RUN_MARKERS)}, nor {CONFIG} "
            f"beside {SCENES}/)")
        raise UserError(f"{run_dir} {what}; pass a folder under <VISPHY_HOME>/runs/")
    files.refuse_tree(run_dir, "run directory")
    files_of = RunDir(run_dir)
    manifest = _or_empty(files_of.read_manifest)
    summary = _or_empty(files_of.read_summary)
    if finished and not summary:
        raise UserError(f"{run_dir}: no readable {SUMMARY} (not a finished run directory: "
                        "rerun its command to finish it)")
    if finished and not ((run_dir / RESULTS_JSONL).is_file()
                         or (run_dir / RESULTS_PARQUET).is_file()):
        raise UserError(f"{run_dir}: no {RESULTS_JSONL} or {RESULTS_PARQUET}")
    status = str(manifest.get("status") or summary.get("status") or "unknown")
    if finished and status != COMPLETE:
        raise UserError(f"{run_dir}: the run is {status}, not {COMPLETE}: rerun its command "
                        "to finish it (it resumes where it stopped)")
    results, skipped = files_of.read_rows()
    order = [str(s) for s in manifest.get("scenes") or []]
    position = {sid: i for i, sid in enumerate(order)}
    results.sort(key=lambda r: position.get(r.scene_id, len(position)))
    done = {r.scene_id for r in results}
    pending = [sid for sid in order if sid not in done]
    if summary:
        source = SUMMARY
    else:
        summary = summarise_rows(results, manifest)
        source = (f"recomputed from {RESULTS_JSONL}: the run has no {SUMMARY} (it was killed "
                  "or is still running)")
    return RunData(run_dir=run_dir, config=_or_empty(files_of.read_config), manifest=manifest,
                   summary=summary, summary_source=source, results=results, pending=pending,
                   skipped_lines=skipped)
