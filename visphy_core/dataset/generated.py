"""Load a benchmark written by `visphy_core.bench.build` into `Scene` objects."""

from __future__ import annotations

import json
from pathlib import Path

from visphy_core.scene import Scene
from visphy_core.video import ClipInfo


def _require(path: Path) -> Path:
    if not path.is_file():
        raise FileNotFoundError(f"missing file: {path}")
    return path


def load_generated(root: Path, split: str | None = None,
                   scene_ids: list[str] | None = None) -> list[Scene]:
    """Scenes of a generated dataset, in metadata order, optionally filtered by split or ids."""
    root = Path(root)
    meta_path = _require(root / "metadata.jsonl")
    scenes = []
    for lineno, line in enumerate(meta_path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            meta = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"malformed JSON in {meta_path} line {lineno}: {exc.msg}") from None
        sid = meta["scene_id"]
        if split is not None and split not in meta.get("splits", []):
            continue
        if scene_ids and sid not in scene_ids:
            continue
        scenes.append(Scene(
            scene_id=sid, dim=meta["dim"],
            clip=ClipInfo(fps=float(meta["fps"]), n_frames=int(meta["n_frames"]),
                          width=int(meta["width"]), height=int(meta["height"])),
            video_path=_require(root / "videos" / f"{sid}.mp4"),
            detection_path=_require(root / "detection_json" / f"{sid}_frame_01.json"),
            spec_path=_require(root / "specs" / f"{sid}.json"),
            trajectory_path=_require(root / "trajectories" / f"{sid}.npz"),
            keyframe_paths={k: root / "keyframes" / f"{sid}_frame_{k:02d}.png" for k in (1, 10)},
            difficulty=meta.get("difficulty"), template_id=meta.get("template_id"),
            dataset=root.name))
    return scenes
