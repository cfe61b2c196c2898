"""Scenes as the pipeline sees them: where a scene's ground truth lives and how to read it.

A `Scene` is a set of paths plus the clip contract (fps, frame count, size). Loading is lazy so a
split of hundreds of scenes costs nothing until a scene is processed.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from visphy_core.infra.errors import SceneDataError, one_line
from visphy_core.infra.video import ClipInfo, decode_video

#: Version tag of the scene specification schema (`visphy_core/spec/spec2d.py`).
SPEC_SCHEMA = "visphy-scene/1"


def read_json(path: Path) -> Any:
    """Read a JSON file, naming the file in the one-line error when it is missing or malformed."""
    if not path.is_file():
        raise FileNotFoundError(f"missing file: {path}")
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"malformed JSON in {path}: {exc.msg} (line {exc.lineno})") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"malformed JSON in {path}: not UTF-8 text (byte {exc.start})") from None


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
    #: Why the scene could not be loaded (a lenient loader keeps the scene so it becomes a
    #: ``data_error`` row instead of aborting the whole dataset).
    load_error: str | None = None

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
        path = self.trajectory_path
        if not path.is_file():
            raise FileNotFoundError(f"missing file: {path}")
        try:
            npz = np.load(path, allow_pickle=False)
            if not isinstance(npz, np.lib.npyio.NpzFile):
                raise ValueError("not an .npz archive")
            with npz:
                return {k: npz[k] for k in npz.files}
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
            reason = "not an .npz archive" if "pickle" in str(exc) else one_line(str(exc))
            raise ValueError(f"unreadable trajectory {path}: {reason}") from None

    def reference_frames(self) -> np.ndarray:
        """Decoded ground-truth clip (N×H×W×3 uint8)."""
        frames, _ = decode_video(self.video_path)
        return frames

    def check_inputs(self, key_frames: list[int] | tuple[int, ...] = (1, 10)) -> np.ndarray:
        """Read every input of the scene once; returns the decoded reference clip.

        Raises `SceneDataError` (one line, naming the file) for a scene that could not be loaded,
        a missing or malformed detection/spec/trajectory file, an unreadable ground-truth video,
        a clip whose frame count or size differs from the scene's contract, or a key frame the
        clip does not have.
        """
        if self.load_error:
            raise SceneDataError(one_line(self.load_error))
        for path, read in ((self.detection_path, lambda: self.detection),
                           (self.spec_path, lambda: self.spec),
                           (self.trajectory_path, lambda: self.trajectory)):
            if path is None:
                continue
            try:
                read()
            except SceneDataError:
                raise
            except Exception as exc:  # noqa: BLE001 - any read error is this scene's bad input
                raise SceneDataError(_describe(exc, path)) from None
        try:
            frames = self.reference_frames()
        except Exception as exc:  # noqa: BLE001
            raise SceneDataError(_describe(exc, self.video_path)) from None
        c = self.clip
        if len(frames) < max(key_frames, default=1):
            raise SceneDataError(
                f"ground-truth video {self.video_path} has {len(frames)} frame(s), fewer than "
                f"the key frame {max(key_frames)} the prompt shows")
        if len(frames) != c.n_frames:
            raise SceneDataError(
                f"ground-truth video {self.video_path} has {len(frames)} frames, the scene's "
                f"contract says {c.n_frames}")
        if frames.shape[1:3] != (c.height, c.width):
            raise SceneDataError(
                f"ground-truth video {self.video_path} is {frames.shape[2]}x{frames.shape[1]}, "
                f"the scene's contract says {c.width}x{c.height}")
        for index in key_frames:
            path = self.keyframe_paths.get(index)
            if path is None or not path.is_file():
                continue  # decoded from the video (checked above)
            try:
                self.key_frame(index)
            except Exception as exc:  # noqa: BLE001
                raise SceneDataError(_describe(exc, path)) from None
        return frames

    def key_frame(self, index: int) -> np.ndarray:
        """Ground-truth frame by 1-based index (the paper's frame 1 and frame 10)."""
        from PIL import Image

        path = self.keyframe_paths.get(index)
        if path is not None and path.is_file():
            with Image.open(path) as img:
                return np.asarray(img.convert("RGB"))
        frames = self.reference_frames()
        if not 1 <= index <= len(frames):
            raise IndexError(f"{self.scene_id}: key frame {index} outside 1..{len(frames)}")
        return frames[index - 1]


def _describe(exc: BaseException, path: Path) -> str:
    """One line for a failed read, naming the file even when the exception does not."""
    message = one_line(str(exc)) or type(exc).__name__
    if str(path) not in message:
        message = f"{path}: {type(exc).__name__}: {message}"
    return message[:500]
