"""Finished run directories as data: find them, load them, and name them for a comparison.

A run directory (written by `visphy_core.execute.run`, laid out as `visphy_core.results.layout`
says, read by `visphy_core.results.load`) holds ``summary.json``, ``results.parquet`` and/or
``results.jsonl`` (one row per scene), ``config.yaml`` and ``manifest.json``; the human-rating
page may add ``human_ratings.jsonl``. `find_runs` accepts run directories and any folder above
them (``visphy-out/runs``, a Hydra multirun sweep), and follows a study's job records
(``jobs/<n>/visphy_job.json``) to the runs they made, so a study is analysed by pointing at its
folder. Labels say ``model/engine`` and, when two runs compared share that, what sets them apart
(``<model>/<engine> prompt.detection=false``): tables and figures need names a reader can tell
apart.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

from visphy_core.analysis.human import read_ratings
from visphy_core.infra.errors import UserError
from visphy_core.results import load as results_load
from visphy_core.results.layout import (
    MANIFEST,
    RATINGS,
    SUMMARY,
    is_finished_run,
    is_run_dir,
    run_status,
)
from visphy_core.results.load import RunData

#: Config keys that never tell two configurations apart (where files go, how the run is tracked
#: and sandboxed, which metrics and judges score it, transport settings).
IGNORED_PREFIXES = ("paths.", "tracking.", "sandbox.", "metrics.", "judge.", "hydra.",
                    "run.progress", "run.summary", "run.cache", "run.prefetch", "run.cost_cap_usd",
                    "run.workers", "run.resume")
IGNORED_SUFFIXES = ("base_url", "api_key_env", "timeout_s", "max_retries", "concurrency",
                    "price.input_usd_per_mtok", "price.output_usd_per_mtok",
                    "price.cached_input_usd_per_mtok")


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
        if is_finished_run(path):
            found[path.resolve()] = None
            continue
        if is_run_dir(path):
            raise UserError(f"{path}: the run is {run_status(path)}, not finished: rerun its "
                            "command to finish it (it resumes where it stopped)")
        under = sorted(p.parent for p in path.rglob(SUMMARY) if is_finished_run(p.parent))
        under += _study_runs(path)
        _say_unfinished(path)
        if not under:
            raise UserError(f"{path}: no finished run directory here (a finished run holds "
                            f"{SUMMARY} and the status finished); point at a run or a folder "
                            "of runs")
        for p in under:
            found[p.resolve()] = None
    return list(found)


def _say_unfinished(folder: Path) -> None:
    """One line on stderr naming the run directories under ``folder`` left out because they
    did not finish (interrupted, failed, stopped by the cost cap, killed or still running)."""
    import sys

    left = sorted({m.parent for name in (MANIFEST, SUMMARY) for m in folder.rglob(name)
                   if is_run_dir(m.parent) and not is_finished_run(m.parent)})
    if left:
        named = ", ".join(f"{p.name} ({run_status(p)})" for p in left[:5])
        more = f" and {len(left) - 5} more" if len(left) > 5 else ""
        print(f"left out {len(left)} unfinished run(s) under {folder}: {named}{more} (rerun a "
              "run's command to finish it)", file=sys.stderr)


def _study_runs(folder: Path) -> list[Path]:
    """The run directories a study's job records under ``folder`` point at (a study's runs live
    in ``paths.runs_dir``, not in its sweep folder), in job order."""
    from visphy_core.results.study_records import read_jobs

    out = []
    for job in read_jobs(folder):
        run_dir = job.get("run_dir")
        if run_dir and is_finished_run(Path(run_dir)):
            out.append(Path(run_dir))
    return out


def load_run(path: str | Path) -> RunData:
    """One finished run directory with its human ratings (`UserError` when ``path`` is not
    one)."""
    run = results_load.load_run(Path(path).expanduser().resolve(), finished=True)
    run.ratings = read_ratings(run.run_dir / RATINGS)
    return run


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
