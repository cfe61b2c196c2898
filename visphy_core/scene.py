"""Scenes as the pipeline sees them: where a scene's ground truth lives and how to read it.

A `Scene` is a set of paths plus the clip contract (fps, frame count, size). Loading is lazy so a
split of hundreds of scenes costs nothing until a scene is processed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from visphy_core.video import ClipInfo, decode_video

#: Version tag of the scene specification schema (`visphy_core/bench/spec.py`).
SPEC_SCHEMA = "visphy-scene/1"


def scene_dim(scene_id: str) -> str:
    """Infer 2D/3D from a VisPhyBench id: `taskNNNNN_NNN` is 2D, `NN_tmpl_NN` is 3D."""
    import re

    if re.fullmatch(r"task\d{5}_\d{3}", scene_id):
        return "2d"
    if re.fullmatch(r"\d+_tmpl_\d+", scene_id):
        return "3d"
    raise ValueError(
        f"scene id {scene_id!r} is neither 2D (taskNNNNN_NNN) nor 3D (NN_tmpl_NN)"
    )


def read_json(path: Path) -> Any:
    """Read a JSON file, naming the file in the one-line error when it is missing or malformed."""
    if not path.is_file():
        raise FileNotFoundError(f"missing file: {path}")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"malformed JSON in {path}: {exc.msg} (line {exc.lineno})") from None


@dataclass(frozen=True)
class Scene:
    """One benchmark scene: its id, its ground-truth files and the clip contract."""

    scene_id: str
    dim: str
    clip: ClipInfo
    video_path: Path
    detection_path: Path | None = None
    spec_path: Path | None = None
    trajectory_path: Path | None = None
    keyframe_paths: dict[int, Path] = field(default_factory=dict)
    difficulty: str | None = None
    template_id: str | None = None
    dataset: str = ""

    @cached_property
    def spec(self) -> dict | None:
        return read_json(self.spec_path) if self.spec_path else None

    @cached_property
    def detection(self) -> dict | None:
        return read_json(self.detection_path) if self.detection_path else None

    @cached_property
    def trajectory(self) -> dict[str, np.ndarray] | None:
        if not self.trajectory_path:
            return None
        with np.load(self.trajectory_path, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}

    def reference_frames(self) -> np.ndarray:
        """Decoded ground-truth clip (N×H×W×3 uint8)."""
        frames, _ = decode_video(self.video_path)
        return frames

    def key_frame(self, index: int) -> np.ndarray:
        """Ground-truth frame by 1-based index (the paper's frame 1 and frame 10)."""
        from PIL import Image

        path = self.keyframe_paths.get(index)
        if path is not None and path.is_file():
            return np.asarray(Image.open(path).convert("RGB"))
        frames = self.reference_frames()
        if not 1 <= index <= len(frames):
            raise IndexError(f"{self.scene_id}: key frame {index} outside 1..{len(frames)}")
        return frames[index - 1]
