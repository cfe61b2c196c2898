"""What a rater rates: one item per (run directory, scene) with a generated clip, its opaque id
and the rater's order.

An item id is a hash of the run directory's name and the scene id: it names nothing a rater could
read (a run directory's name holds the model and the engine), yet it is the same on every
machine and for every rater, so ratings of copies of the same runs line up. The order is a
shuffle seeded by the rater id: the same rater always gets the same order (and resumes it), two
raters get different ones.
"""

from __future__ import annotations

import hashlib
import logging
import random
from dataclasses import dataclass
from pathlib import Path

from visphy_core.execute.run_scenes import load_run_scenes
from visphy_core.infra import files
from visphy_core.infra.errors import UserError
from visphy_core.results import layout
from visphy_core.results.layout import CONFIG, is_run_dir
from visphy_core.results.run_dir import RunDir

log = logging.getLogger("visphy.human")

#: Version of the id and order derivations (changing either would orphan existing ratings).
ID_VERSION = "visphy-rate/1"


@dataclass(frozen=True)
class RatingItem:
    """One thing to rate: the generated clip of ``scene_id`` in ``run_dir`` beside the scene's
    ground-truth clip ``reference``."""

    item: str
    run_dir: Path
    scene_id: str
    generated: Path
    reference: Path


def item_id(run_dir: Path, scene_id: str) -> str:
    """The opaque, stable id of a (run directory, scene) pair."""
    digest = hashlib.sha256(f"{ID_VERSION}\0{Path(run_dir).name}\0{scene_id}".encode())
    return digest.hexdigest()[:16]


def find_run_dirs(paths: list[str | Path]) -> list[Path]:
    """Run directories named by ``paths``: each path is a run directory or a folder holding run
    directories at any depth (`UserError` for a missing path or when none is found)."""
    found: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if not path.exists():
            raise UserError(f"{path} does not exist")
        if is_run_dir(path):
            found.append(path.resolve())
            continue
        found += sorted(p.parent.resolve() for p in path.rglob(CONFIG)
                        if is_run_dir(p.parent) and not any(is_run_dir(a) for a in
                                                             p.parent.parents))
    unique = list(dict.fromkeys(found))
    for run_dir in unique:  # a linked clip or ratings file: the whole run is refused, one line
        files.refuse_tree(run_dir, "run directory")
    if not unique:
        raise UserError(f"no run directory under {', '.join(str(p) for p in paths)} (a run "
                        "directory holds config.yaml and scenes/)")
    return unique


def collect_items(run_dirs: list[Path]) -> list[RatingItem]:
    """Every scene of ``run_dirs`` with a generated clip, sorted by item id. Two run
    directories with the same name (copies) give the same ids: only the first is kept."""
    items: dict[str, RatingItem] = {}
    for run_dir in run_dirs:
        run_files = RunDir(run_dir)
        scene_ids = sorted(p.parent.name for p in run_files.scenes.glob(f"*/{layout.VIDEO}"))
        if not scene_ids:
            continue
        scenes = load_run_scenes(run_dir, scene_ids)
        for scene_id in scene_ids:
            scene = scenes.get(scene_id)
            if scene is None or not Path(scene.video_path).is_file():
                log.warning("%s: no ground-truth clip for scene %s; not rated", run_dir, scene_id)
                continue
            key = item_id(run_dir, scene_id)
            if key in items:
                log.warning("%s repeats the run directory %s; its copy is not rated twice",
                            run_dir, items[key].run_dir)
                continue
            items[key] = RatingItem(key, run_dir, scene_id,
                                    run_files.scene_dir(scene_id) / layout.VIDEO,
                                    Path(scene.video_path).resolve())
    if not items:
        raise UserError("no generated clip to rate in "
                        + ", ".join(str(d) for d in run_dirs))
    return [items[k] for k in sorted(items)]


def rater_order(items: list[RatingItem], rater: str) -> list[RatingItem]:
    """``items`` shuffled by a seed derived from ``rater`` (the same rater, the same order)."""
    seed = int.from_bytes(hashlib.sha256(f"{ID_VERSION}\0{rater}".encode()).digest()[:8],
                          "little")
    ordered = sorted(items, key=lambda i: i.item)
    random.Random(seed).shuffle(ordered)
    return ordered
