"""Load a benchmark written by `visphy_plugins.datasets.visphybench.build` into `Scene` objects."""

from __future__ import annotations

import json
from pathlib import Path

from visphy_core.api.media import ClipInfo
from visphy_core.api.scene import Scene
from visphy_core.api.storage import files


def _require(path: Path) -> Path:
    if not path.is_file():
        raise FileNotFoundError(f"missing file: {path}")
    return path


def load_generated(root: Path, split: str | None = None,
                   scene_ids: list[str] | None = None, strict: bool = True) -> list[Scene]:
    """Scenes of a generated dataset, in metadata order, optionally filtered by split or ids.

    ``strict=False`` (what a run uses) does not check a scene's files here: a missing or broken
    file of one scene, or an unusable metadata line that still names its scene, gives a `Scene`
    that becomes a ``data_error`` row when processed, and the other scenes still run. A missing
    or unreadable ``metadata.jsonl`` is an error either way.
    """
    root = Path(root)
    req = _require if strict else (lambda path: path)
    meta_path = _require(root / "metadata.jsonl")
    # a dataset folder may come from elsewhere: links, special and oversized files are refused
    refused = files.scan_tree(root)
    for name in ("metadata.jsonl", "videos", "detection_json", "specs", "trajectories",
                 "keyframes"):
        if name in refused:
            raise files.ForeignFileError(f"refused to read {root / name}: it is {refused[name]}")
    scenes = []
    for lineno, line in enumerate(meta_path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            meta = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"malformed JSON in {meta_path} line {lineno}: {exc.msg}") from None
        if not isinstance(meta, dict) or not isinstance(meta.get("scene_id"), str):
            raise ValueError(f"{meta_path} line {lineno}: no scene_id")
        sid = meta["scene_id"]
        if split is not None and split not in meta.get("splits", []):
            continue
        if scene_ids and sid not in scene_ids:
            continue
        paths = dict(
            video_path=root / "videos" / f"{sid}.mp4",
            detection_path=root / "detection_json" / f"{sid}_frame_01.json",
            spec_path=root / "specs" / f"{sid}.json",
            trajectory_path=root / "trajectories" / f"{sid}.npz")
        load_error = None
        bad = [f"refused to read {p}: it is {refused[str(p.relative_to(root))]}"
               for p in (*paths.values(), *(root / "keyframes" / f"{sid}_frame_{k:02d}.png"
                                            for k in (1, 10)))
               if str(p.relative_to(root)) in refused]
        if bad:
            if strict:
                raise files.ForeignFileError(bad[0])
            load_error = bad[0]
        try:
            clip = ClipInfo(fps=float(meta["fps"]), n_frames=int(meta["n_frames"]),
                            width=int(meta["width"]), height=int(meta["height"]))
            dim = str(meta["dim"])
        except (KeyError, TypeError, ValueError) as exc:
            if strict:
                raise ValueError(f"{meta_path} line {lineno}: bad or missing field "
                                 f"{exc}") from None
            load_error = load_error or f"{meta_path} line {lineno}: bad or missing field {exc}"
            clip, dim = ClipInfo(fps=0.0, n_frames=0, width=0, height=0), "2d"
        scenes.append(Scene(
            scene_id=sid, dim=dim, clip=clip,
            **{name: req(path) for name, path in paths.items()},
            keyframe_paths={k: root / "keyframes" / f"{sid}_frame_{k:02d}.png" for k in (1, 10)},
            difficulty=meta.get("difficulty"), template_id=meta.get("template_id"),
            dataset=root.name, load_error=load_error))
    return scenes
