"""Find a run's ground truth on disk without loading, building or touching the dataset.

A report must not regenerate a benchmark (loading the generated dataset builds what is missing:
minutes of simulation for a page), so it looks for the files instead, in the layout every
VisPhyBench dataset shares (the published one, the generated one, ``tiny``): a folder holding
``videos/<scene_id>.mp4``, with ``keyframes/<scene_id>_frame_NN.png``,
``specs/<scene_id>.json`` and ``detection_json/<scene_id>_frame_01.json`` beside it when the
dataset has them. It searches ``dataset.root`` and ``paths.data_dir`` of the run's config (a
relative path is relative to where the run was started, found from where its run directory is).
Where several folders hold a scene (a lossless and a published-style build of the same
benchmark), the one matching the config (``dataset.split``, ``dataset.lossless``, the seed) wins.
A scene found nowhere gets the reason, and the report says so.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from visphy_core.results.load import RunData

#: How deep under a search root a dataset folder (the parent of ``videos/``) may be.
MAX_DEPTH = 3
#: Folders of a dataset that never hold another dataset: not descended into.
LEAVES = {"videos", "keyframes", "specs", "trajectories", "detection_json", "meta", "cache",
          "runs", "mlartifacts", "scenes"}


@dataclass
class GroundTruth:
    """Where one scene's ground truth lies (paths that exist), or why it was not found."""

    scene_id: str
    root: Path | None = None
    video: Path | None = None
    keyframes: dict[int, Path] = field(default_factory=dict)
    spec: Path | None = None
    detection: Path | None = None
    missing: str | None = None


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


def _resolve(run: RunData, value: object) -> list[Path]:
    if not value:
        return []
    path = Path(str(value)).expanduser()
    if path.is_absolute():
        return [path]
    base = _run_base(run)
    out = [base / path] if base is not None else []
    return out + [Path.cwd() / path]


def search_candidates(run: RunData) -> list[Path]:
    """Every folder the config names for its data (``dataset.root``, ``$VISPHYBENCH_ROOT`` for
    the original layout, ``paths.data_dir``), whether it exists or not."""
    candidates = _resolve(run, run.cfg("dataset.root"))
    if str(run.cfg("dataset.source", "")) == "original" and os.environ.get("VISPHYBENCH_ROOT"):
        candidates.append(Path(os.environ["VISPHYBENCH_ROOT"]))
    return candidates + _resolve(run, run.cfg("paths.data_dir"))


def search_roots(run: RunData) -> list[Path]:
    """The `search_candidates` that exist, each once."""
    roots: list[Path] = []
    for path in search_candidates(run):
        if path.is_dir() and path.resolve() not in [r.resolve() for r in roots]:
            roots.append(path)
    return roots


def _searched(run: RunData) -> str:
    """Where the search looked, for a scene not found: every named folder, a missing one
    marked as such."""
    named = list(dict.fromkeys(search_candidates(run)))
    return ", ".join(str(p) if p.is_dir() else f"{p} (missing)" for p in named) \
        or "nowhere (the config names no data folder)"


def _dataset_folders(root: Path) -> list[Path]:
    """Folders under ``root`` (itself included) that hold a ``videos/`` folder."""
    found: list[Path] = []
    stack = [(root, 0)]
    while stack:
        folder, depth = stack.pop()
        if (folder / "videos").is_dir():
            found.append(folder)
        if depth >= MAX_DEPTH:
            continue
        try:
            entries = sorted(os.scandir(folder), key=lambda e: e.name, reverse=True)
        except OSError:
            continue
        stack += [(Path(e.path), depth + 1) for e in entries
                  if e.is_dir(follow_symlinks=False) and e.name not in LEAVES
                  and not e.name.startswith(".")]
    return found


def _preference(folder: Path, run: RunData, primary: Path | None) -> tuple[int, ...]:
    """Higher is better: under ``dataset.root``, then the split, losslessness and seed that
    the config names."""
    name = folder.name
    split = run.cfg("dataset.split")
    lossless = bool(run.cfg("dataset.lossless", False))
    seed = run.cfg("dataset.seed")
    under_root = primary is not None and primary.resolve() in [folder.resolve(),
                                                               *folder.resolve().parents]
    return (int(under_root),
            int(split is not None and name == str(split)),
            int(("lossless" in name) == lossless),
            int(seed is not None and re.search(rf"seed{seed}(\D|$)", name) is not None))


def locate_ground_truth(run: RunData, scene_ids: list[str]) -> dict[str, GroundTruth]:
    """Each scene's ground truth, or a `GroundTruth` with ``missing`` saying where it looked."""
    roots = search_roots(run)
    primary = roots[0] if run.cfg("dataset.root") and roots else None
    folders = [f for root in roots for f in _dataset_folders(root)]
    hits = {f: {sid for sid in scene_ids if (f / "videos" / f"{sid}.mp4").is_file()}
            for f in folders}
    ranked = sorted((f for f in folders if hits[f]),
                    key=lambda f: (len(hits[f]), *_preference(f, run, primary)), reverse=True)
    where = _searched(run)
    out: dict[str, GroundTruth] = {}
    for sid in scene_ids:
        folder = next((f for f in ranked if sid in hits[f]), None)
        if folder is None:
            out[sid] = GroundTruth(sid, missing=f"ground truth not found: no videos/{sid}.mp4 "
                                                f"under {where} (dataset moved or deleted?)")
            continue
        frames = {}
        for path in (folder / "keyframes").glob(f"{sid}_frame_*.png"):
            match = re.fullmatch(rf"{re.escape(sid)}_frame_(\d+)\.png", path.name)
            if match:
                frames[int(match.group(1))] = path
        spec = folder / "specs" / f"{sid}.json"
        detection = folder / "detection_json" / f"{sid}_frame_01.json"
        out[sid] = GroundTruth(sid, root=folder, video=folder / "videos" / f"{sid}.mp4",
                               keyframes=frames, spec=spec if spec.is_file() else None,
                               detection=detection if detection.is_file() else None)
    return out
