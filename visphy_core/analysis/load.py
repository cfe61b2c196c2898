"""Finished run directories as data: find them, load them, and name them for a comparison.

A run directory (written by `visphy_core.execute.run`) holds ``summary.json``, ``results.parquet``
and/or
``results.jsonl`` (one row per scene), ``config.yaml`` and ``manifest.json``; the human-rating
page may add ``human_ratings.jsonl``. `find_runs` accepts run directories and any folder above
them (``visphy-out/runs``, a Hydra multirun sweep), and follows a study's job records
(``jobs/<n>/visphy_job.json``) to the runs they made, so a study is analysed by pointing at its
folder. Labels say ``model/engine`` and, when two runs compared share that, what sets them apart
(``oracle/threejs prompt.detection=false``): tables and figures need names a reader can tell apart.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import pandas as pd

from visphy_core.analysis.human import read_ratings
from visphy_core.infra import files
from visphy_core.infra.errors import UserError

SUMMARY = "summary.json"
#: The scene-row fields the analysis reads, with the value a row without the field means.
ROW_DEFAULTS = {"scene_id": None, "dim": None, "difficulty": None, "model_success": False,
                "system_success": False, "fallback": False, "attempts": 0,
                "failure_class": None, "first_failure_class": None}
RESULTS = ("results.parquet", "results.jsonl")

#: Config keys that never tell two configurations apart (where files go, how the run is tracked
#: and sandboxed, which metrics and judges score it, transport settings).
IGNORED_PREFIXES = ("paths.", "tracking.", "sandbox.", "metrics.", "judge.", "hydra.",
                    "run.progress", "run.cache", "run.prefetch", "run.cost_cap_usd")
IGNORED_SUFFIXES = ("base_url", "api_key_env", "timeout_s", "max_retries", "concurrency",
                    "price.input_usd_per_mtok", "price.output_usd_per_mtok",
                    "price.cached_input_usd_per_mtok")


@dataclass
class RunData:
    """One finished (or interrupted) run: its resolved config, summary, manifest and scene rows.

    ``ratings`` holds the run's human ratings (`visphy_core.analysis.human.read_ratings`: one row
    per rater and item, re-ratings resolved), empty when nobody rated it.
    """

    run_dir: Path
    config: dict
    summary: dict
    manifest: dict
    results: pd.DataFrame
    ratings: pd.DataFrame = field(default_factory=lambda: read_ratings(None))
    _label: str | None = field(default=None, repr=False)

    @property
    def model(self) -> str:
        return str(_get(self.config, "model.name") or self.summary.get("model") or "?")

    @property
    def engine(self) -> str:
        return str(_get(self.config, "engine.name") or self.summary.get("engine") or "?")

    @property
    def base_label(self) -> str:
        """``model/engine``."""
        return f"{self.model}/{self.engine}"

    @property
    def label(self) -> str:
        """The name this run has in a comparison (set by `load_runs` / `label_runs`), else
        ``model/engine``."""
        return self._label or self.base_label


def _get(config: dict, dotted: str) -> Any:
    node: Any = config
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def is_run_dir(path: Path) -> bool:
    """A run directory: ``summary.json`` beside ``results.parquet`` or ``results.jsonl``."""
    return (path / SUMMARY).is_file() and any((path / r).is_file() for r in RESULTS)


def find_runs(*paths: str | Path) -> list[Path]:
    """Every run directory at or below ``paths``, or named by a study's job records under them
    (sorted per path, each once).

    Raises `UserError` for a path that does not exist or holds no run directory.
    """
    if not paths:
        raise UserError("no path given: name run directories or a folder that holds them")
    found: dict[Path, None] = {}
    for raw in paths:
        path = Path(raw).expanduser()
        if not path.exists():
            raise UserError(f"{path}: no such file or directory")
        if path.is_file():
            path = path.parent
        if is_run_dir(path):
            found[path.resolve()] = None
            continue
        under = sorted(p.parent for p in path.rglob(SUMMARY) if is_run_dir(p.parent))
        under += _study_runs(path)
        if not under:
            raise UserError(f"{path}: no run directory here (a run directory holds {SUMMARY} and "
                            f"{' or '.join(RESULTS)}); point at a run or a folder of runs")
        for p in under:
            found[p.resolve()] = None
    return list(found)


def _study_runs(folder: Path) -> list[Path]:
    """The run directories a study's job records under ``folder`` point at (a study's runs live
    in ``paths.runs_dir``, not in its sweep folder), in job order."""
    from visphy_core.results.study_records import read_jobs

    out = []
    for job in read_jobs(folder):
        run_dir = job.get("run_dir")
        if run_dir and is_run_dir(Path(run_dir)):
            out.append(Path(run_dir))
    return out


def _read_json(path: Path, required: bool) -> dict:
    if not path.is_file():
        if required:
            raise UserError(f"{path}: missing (not a finished run directory)")
        return {}
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise UserError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a JSON object")
    return data


def _read_config(run_dir: Path) -> dict:
    path = run_dir / "config.yaml"
    if not path.is_file():
        return {}
    from omegaconf import OmegaConf

    try:
        cfg = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    except Exception as exc:  # noqa: BLE001 - any parse failure is the file's fault
        raise UserError(f"{path}: not a readable config ({exc})") from None
    return cfg if isinstance(cfg, dict) else {}


def _read_results(run_dir: Path) -> pd.DataFrame:
    """The scene rows: Parquet (written when the run closes) else the JSON lines written as it
    goes (an interrupted run); a truncated last line is dropped; one row per scene (the last)."""
    parquet, jsonl = (run_dir / r for r in RESULTS)
    df = None
    if parquet.is_file():
        try:
            df = pd.read_parquet(parquet)
        except Exception:  # noqa: BLE001 - fall back to the JSON lines
            df = None
    if df is None and jsonl.is_file():
        rows = []
        for line in jsonl.read_text().splitlines():
            try:
                rows.append(json.loads(line))
            except ValueError:
                continue
        df = pd.DataFrame(rows)
    if df is None:
        raise UserError(f"{run_dir}: no readable {' or '.join(RESULTS)}")
    if len(df) and "scene_id" not in df.columns:
        raise UserError(f"{run_dir}: results have no scene_id column")
    if len(df):
        df = df.drop_duplicates("scene_id", keep="last").reset_index(drop=True)
    for column, default in ROW_DEFAULTS.items():   # rows of older versions lack some fields
        if column not in df.columns:
            df[column] = default
    return df


def load_run(path: str | Path) -> RunData:
    """One run directory (`UserError` when ``path`` is not one)."""
    run_dir = Path(path).expanduser()
    if not is_run_dir(run_dir):
        raise UserError(f"{run_dir}: not a run directory (a run directory holds {SUMMARY} and "
                        f"{' or '.join(RESULTS)})")
    files.refuse_tree(run_dir, "run directory")
    return RunData(run_dir=run_dir.resolve(), config=_read_config(run_dir),
                   summary=_read_json(run_dir / SUMMARY, required=True),
                   manifest=_read_json(run_dir / "manifest.json", required=False),
                   results=_read_results(run_dir),
                   ratings=read_ratings(run_dir / "human_ratings.jsonl"))


def load_runs(paths: Iterable[str | Path]) -> list[RunData]:
    """Every run at or below ``paths`` (see `find_runs`), labelled for comparison."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    runs = [load_run(p) for p in find_runs(*paths)]
    for run, label in zip(runs, label_runs(runs)):
        run._label = label
    return runs


# ---------------------------------------------------------------------------- labels


def flatten(config: Any, prefix: str = "") -> dict[str, Any]:
    """``{"a.b.c": value}`` for every leaf of a nested config (lists are leaves)."""
    if not isinstance(config, dict):
        return {prefix: config} if prefix else {}
    out: dict[str, Any] = {}
    for key, value in config.items():
        name = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, dict) and value:
            out.update(flatten(value, name))
        else:
            out[name] = value
    return out


def _label_keys(config: dict) -> dict[str, Any]:
    """The flattened config with the dataset folded into one short ``dataset`` value (its name,
    then ``limit=N`` or the number of scenes picked): its other keys follow from the name."""
    flat = {k: v for k, v in flatten(config).items() if not k.startswith("dataset.")}
    data = config.get("dataset") if isinstance(config.get("dataset"), dict) else {}
    if data:
        text = str(data.get("name"))
        if data.get("scenes"):
            text += f"[{len(data['scenes'])} scenes]"
        if data.get("limit") is not None:
            text += f"[limit {data['limit']}]"
        if data.get("seed") not in (None, 0):
            text += f"[seed {data['seed']}]"
        flat["dataset"] = text
    return flat


def _distinguishing(key: str) -> bool:
    return not (key.startswith(IGNORED_PREFIXES) or key.endswith(IGNORED_SUFFIXES))


def _show(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_show(v) for v in value) + "]"
    text = str(value)
    if "/" in text and len(text) > 24:   # a path (model.source=...): its last part says enough
        text = Path(text).name or text
    return text


def label_runs(runs: list[RunData]) -> list[str]:
    """A unique, readable label per run: ``model/engine`` plus ``key=value`` for each config key
    whose value differs between runs sharing that ``model/engine``; runs whose configs agree are
    told apart by their directory names."""
    labels = [r.base_label for r in runs]
    groups: dict[str, list[int]] = {}
    for i, label in enumerate(labels):
        groups.setdefault(label, []).append(i)
    for members in groups.values():
        if len(members) < 2:
            continue
        flats = [_label_keys(runs[i].config) for i in members]
        keys = sorted({k for f in flats for k in f if _distinguishing(k)})
        differing = [k for k in keys if len({_show(f.get(k)) for f in flats}) > 1]
        for i, flat in zip(members, flats):
            extra = " ".join(f"{k}={_show(flat.get(k))}" for k in differing)
            labels[i] = f"{labels[i]} {extra}".strip()
    seen: dict[str, int] = {}
    for label in labels:
        seen[label] = seen.get(label, 0) + 1
    for i, label in enumerate(labels):
        if seen[label] > 1:
            labels[i] = f"{label} [{runs[i].run_dir.name}]"
    return labels
