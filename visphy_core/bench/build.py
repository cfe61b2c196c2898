"""Write a generated benchmark to disk in the VisPhyBench layout, plus visphy's exact ground truth.

Layout of ``<data_dir>/<name>/``: ``videos/<id>.mp4``, ``detection_json/<id>_frame_01.json``,
``keyframes/<id>_frame_01.png`` and ``_frame_10.png``, ``specs/<id>.json``,
``trajectories/<id>.npz``, ``difficulty_table.json``, ``metadata.jsonl`` and, written last so its
presence means the build completed, ``BUILD_INFO.json``. Every file is written atomically, and
nothing depends on the clock, so two builds are byte-identical.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import Callable

import numpy as np

from visphy_core.bench.box2d_sim import Rollout, simulate_2d, trajectory_digest
from visphy_core.bench.detection import detection_from_spec
from visphy_core.bench.raster2d import render_clip_2d
from visphy_core.video import encode_video

#: Bump when anything that changes the written files changes: a dataset built by another
#: builder version is rebuilt on first use.
BUILDER_VERSION = "visphy-bench/1"
KEY_FRAMES = (1, 10)


def _mini() -> list[dict]:
    from visphy_core.bench.templates_mini import mini_specs

    return mini_specs()


#: Dataset name → function returning its annotated scene specs (in a fixed order).
BUILDERS: dict[str, Callable[[], list[dict]]] = {"mini": _mini}


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def _json_bytes(obj) -> bytes:
    return (json.dumps(obj, indent=1, sort_keys=False) + "\n").encode()


def _png_bytes(frame: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(frame).save(buf, format="PNG")
    return buf.getvalue()


def _npz_bytes(rollout: Rollout) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, body_ids=np.array(rollout.body_ids, dtype=str),
             frame_poses=rollout.frame_poses, step_poses=rollout.step_poses,
             frame_steps=rollout.frame_steps, frame_times_s=rollout.frame_times_s)
    return buf.getvalue()


def write_scene(spec: dict, root: Path, split: str) -> dict:
    """Simulate, render and write one scene; returns its metadata line."""
    sid = spec["scene_id"]
    rollout = simulate_2d(spec)
    digest = trajectory_digest(rollout)
    spec = dict(spec)
    spec["ground_truth"] = dict(spec.get("ground_truth", {}),
                                trajectory=f"trajectories/{sid}.npz", events=rollout.events)
    spec["digest_sha256"] = digest
    world = spec["world"]
    width, height = world["units"]["canvas_px"]
    fps = world["video_fps"]
    frames = render_clip_2d(spec, rollout.frame_poses)
    encode_video(frames, root / "videos" / f"{sid}.mp4", fps)
    for k in KEY_FRAMES:
        _atomic_write(root / "keyframes" / f"{sid}_frame_{k:02d}.png", _png_bytes(frames[k - 1]))
    _atomic_write(root / "detection_json" / f"{sid}_frame_01.json",
                  _json_bytes(detection_from_spec(spec, rollout.frame_poses[0])))
    _atomic_write(root / "specs" / f"{sid}.json", _json_bytes(spec))
    _atomic_write(root / "trajectories" / f"{sid}.npz", _npz_bytes(rollout))
    return {"scene_id": sid, "template_id": spec.get("template_id"), "dim": spec["dim"],
            "splits": [split], "difficulty": spec["difficulty"]["label"], "fps": fps,
            "n_frames": int(len(frames)), "width": int(width), "height": int(height),
            "digest_sha256": digest}


def build_dataset(name: str, data_dir: Path, progress: bool = True) -> Path:
    """Build dataset ``name`` under ``data_dir`` (overwriting), with a progress bar."""
    if name not in BUILDERS:
        raise ValueError(f"unknown generated dataset {name!r}; valid: {', '.join(sorted(BUILDERS))}")
    root = Path(data_dir) / name
    (root / "BUILD_INFO.json").unlink(missing_ok=True)
    specs = BUILDERS[name]()
    if progress:
        from rich.progress import track

        specs_iter = track(specs, description=f"building {name}", transient=True)
    else:
        specs_iter = specs
    lines = [write_scene(spec, root, split=name) for spec in specs_iter]
    table = {spec["scene_id"]: {"difficulty": spec["difficulty"]["label"],
                                "features": spec["difficulty"].get("features", {})}
             for spec in specs}
    _atomic_write(root / "difficulty_table.json", _json_bytes(table))
    _atomic_write(root / "metadata.jsonl",
                  "".join(json.dumps(line) + "\n" for line in lines).encode())
    _atomic_write(root / "BUILD_INFO.json", _json_bytes(
        {"builder": BUILDER_VERSION, "name": name, "n_scenes": len(lines),
         "scene_ids": [line["scene_id"] for line in lines]}))
    return root


def ensure_dataset(name: str, data_dir: Path, progress: bool = True) -> Path:
    """The dataset's root, building it first when missing or built by another builder version."""
    root = Path(data_dir) / name
    info = root / "BUILD_INFO.json"
    if info.is_file():
        try:
            if json.loads(info.read_text()).get("builder") == BUILDER_VERSION:
                return root
        except json.JSONDecodeError:
            pass
    return build_dataset(name, data_dir, progress=progress)
