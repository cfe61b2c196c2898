"""Find a run's ground truth on disk by asking its dataset plugin, without loading, building or
touching the dataset.

A report must not regenerate a benchmark (loading a generated dataset builds what is missing:
minutes of simulation for a page), so it asks the plugin of the run's ``dataset.source`` where
the files are (`visphy_core.api.dataset.Dataset.locate_ground_truth`), handing it the run's
config and how a path the config names resolves (a relative path is relative to where the run
was started, found from where its run directory is). A config that names no source asks every
installed dataset. A scene found nowhere gets the reason, and the report says so.
"""

from __future__ import annotations

from pathlib import Path

from visphy_core.api.dataset import FinishedRun, GroundTruth
from visphy_core.results.load import RunData

__all__ = ["GroundTruth", "locate_ground_truth"]


def _run_base(run: RunData) -> Path | None:
    """The directory the run was started from: ``run_dir`` is ``<base>/<paths.runs_dir>/<name>``."""
    runs_dir = run.cfg("paths.runs_dir")
    if not runs_dir:
        return None
    runs = Path(str(runs_dir))
    parent = run.run_dir.resolve().parent
    if runs.is_absolute():
        return None
    parts = runs.parts
    if parent.parts[-len(parts):] != parts:
        return None
    return Path(*parent.parts[:-len(parts)]) if len(parent.parts) > len(parts) else Path("/")


def _resolver(run: RunData):
    base = _run_base(run)

    def paths(value: object) -> list[Path]:
        if not value:
            return []
        path = Path(str(value)).expanduser()
        if path.is_absolute():
            return [path]
        return ([base / path] if base is not None else []) + [Path.cwd() / path]

    return paths


def _datasets(run: RunData) -> tuple[list[tuple[str, object]], str | None]:
    """(name, dataset) to ask, and the reason when there is none."""
    from visphy_core.api.registry import get_registry

    table = get_registry().datasets
    source = run.cfg("dataset.source")
    if not source:
        return [(name, table[name][0]()) for name in sorted(table)], None
    if str(source) not in table:
        return [], f"dataset.source={source} is not an installed dataset"
    return [(str(source), table[str(source)][0]())], None


def locate_ground_truth(run: RunData, scene_ids: list[str]) -> dict[str, GroundTruth]:
    """Each scene's ground truth, or a `GroundTruth` with ``missing`` saying where it looked."""
    finished = FinishedRun(cfg=run.cfg, paths=_resolver(run))
    datasets, why = _datasets(run)
    answers = [(name, ds.locate_ground_truth(finished, list(scene_ids))) for name, ds in datasets]
    out: dict[str, GroundTruth] = {}
    for sid in scene_ids:
        found = [a[sid] for _, a in answers if sid in a]
        hit = next((g for g in found if g.missing is None), None)
        if hit is None and found:
            hit = found[0]
        if hit is None:
            said = why or (f"dataset {datasets[0][0]} does not say where its ground truth lies"
                           if len(datasets) == 1 else "no installed dataset knows this scene")
            hit = GroundTruth(sid, missing=f"ground truth not found: {said}")
        out[sid] = hit
    return out
