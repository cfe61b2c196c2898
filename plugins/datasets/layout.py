"""Where a finished run's ground truth lies in the folder layout every VisPhyBench dataset shares
(the published one, the generated one, ``tiny``, a Hugging Face export): a folder holding
``videos/<scene_id>.mp4``, with ``keyframes/<scene_id>_frame_NN.png``, ``specs/<scene_id>.json``
and ``detection_json/<scene_id>_frame_01.json`` beside it when the dataset has them.

`locate_in_layout` implements `Dataset.locate_ground_truth` for these datasets: it looks for
the files without loading, building or touching the dataset, under ``dataset.root`` and
``paths.data_dir`` of the run's config (and any folder the dataset adds, such as
``$VISPHYBENCH_ROOT`` for the published layout). Where several folders hold a scene (a lossless
and a published-style build of the same benchmark), the one matching the config
(``dataset.split``, ``dataset.lossless``, the seed) wins.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

from visphy_core.api.dataset import FinishedRun, GroundTruth

#: How deep under a search root a dataset folder (the parent of ``videos/``) may be.
MAX_DEPTH = 3
#: Folders of a dataset that never hold another dataset: not descended into.
LEAVES = {"videos", "keyframes", "specs", "trajectories", "detection_json", "meta", "cache",
          "runs", "mlartifacts", "scenes"}


def search_candidates(run: FinishedRun, extra: Sequence[Path] = ()) -> list[Path]:
    """Every folder the config names for its data (``dataset.root``, then ``extra``, then
    ``paths.data_dir``), whether it exists or not."""
    return [*run.paths(run.cfg("dataset.root", None)), *extra,
            *run.paths(run.cfg("paths.data_dir", None))]


def _search_roots(candidates: list[Path]) -> list[Path]:
    """The candidates that exist, each once."""
    roots: list[Path] = []
    for path in candidates:
        if path.is_dir() and path.resolve() not in [r.resolve() for r in roots]:
            roots.append(path)
    return roots


def _searched(candidates: list[Path]) -> str:
    """Where the search looked, for a scene not found: every named folder, a missing one
    marked as such."""
    named = list(dict.fromkeys(candidates))
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


def _preference(folder: Path, run: FinishedRun, primary: Path | None) -> tuple[int, ...]:
    """Higher is better: under ``dataset.root``, then the split, losslessness and seed that
    the config names."""
    name = folder.name
    split = run.cfg("dataset.split", None)
    lossless = bool(run.cfg("dataset.lossless", False))
    seed = run.cfg("dataset.seed", None)
    under_root = primary is not None and primary.resolve() in [folder.resolve(),
                                                               *folder.resolve().parents]
    return (int(under_root),
            int(split is not None and name == str(split)),
            int(("lossless" in name) == lossless),
            int(seed is not None and re.search(rf"seed{seed}(\D|$)", name) is not None))


def _scene_files(folder: Path, sid: str) -> GroundTruth:
    frames = {}
    for path in (folder / "keyframes").glob(f"{sid}_frame_*.png"):
        match = re.fullmatch(rf"{re.escape(sid)}_frame_(\d+)\.png", path.name)
        if match:
            frames[int(match.group(1))] = path
    spec = folder / "specs" / f"{sid}.json"
    detection = folder / "detection_json" / f"{sid}_frame_01.json"
    return GroundTruth(sid, root=folder, video=folder / "videos" / f"{sid}.mp4",
                       keyframes=frames, spec=spec if spec.is_file() else None,
                       detection=detection if detection.is_file() else None)


def locate_in_layout(run: FinishedRun, scene_ids: list[str],
                     extra: Sequence[Path] = ()) -> dict[str, GroundTruth]:
    """Each scene's ground truth, or a `GroundTruth` with ``missing`` saying where it looked."""
    candidates = search_candidates(run, extra)
    roots = _search_roots(candidates)
    primary = roots[0] if run.cfg("dataset.root", None) and roots else None
    folders = [f for root in roots for f in _dataset_folders(root)]
    hits = {f: {sid for sid in scene_ids if (f / "videos" / f"{sid}.mp4").is_file()}
            for f in folders}
    ranked = sorted((f for f in folders if hits[f]),
                    key=lambda f: (len(hits[f]), *_preference(f, run, primary)), reverse=True)
    where = _searched(candidates)
    out: dict[str, GroundTruth] = {}
    for sid in scene_ids:
        folder = next((f for f in ranked if sid in hits[f]), None)
        out[sid] = _scene_files(folder, sid) if folder is not None else GroundTruth(
            sid, missing=f"ground truth not found: no videos/{sid}.mp4 under {where} "
                         "(dataset moved or deleted?)")
    return out
