"""Video I/O with PyAV: deterministic H.264 encoding, decoding, normalisation, frame hashing.

Everything that reads or writes a clip goes through here, so the reference clip and the generated
clip are encoded and decoded the same way before they are compared.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

#: x264 settings used for every clip visphy writes. One thread and a fixed preset make the
#: encoder's output byte-identical for identical frames; crf 12 keeps the flat PHYRE palette
#: crisp (codec noise stays well below the differences the metrics are meant to see).
H264_OPTIONS = {"crf": "12", "preset": "medium", "threads": "1", "tune": "animation"}


@dataclass(frozen=True)
class ClipInfo:
    """What a decoded clip looks like: the contract a render must meet to be compared."""

    fps: float
    n_frames: int
    width: int
    height: int


def frame_digest(frame: np.ndarray) -> str:
    """SHA-256 of a frame's raw RGB bytes: the determinism fingerprint of one frame."""
    arr = np.ascontiguousarray(frame, dtype=np.uint8)
    h = hashlib.sha256()
    h.update(f"{arr.shape}".encode())
    h.update(arr.tobytes())
    return h.hexdigest()


def encode_video(frames: np.ndarray | list[np.ndarray], path: str | Path, fps: float) -> Path:
    """Write RGB uint8 frames (N×H×W×3) to an H.264 MP4 atomically (temp file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = [np.ascontiguousarray(f, dtype=np.uint8) for f in frames]
    if not frames:
        raise ValueError(f"cannot encode an empty clip to {path}")
    height, width = frames[0].shape[:2]
    if height % 2 or width % 2:
        raise ValueError(f"H.264 yuv420p needs even dimensions, got {width}x{height} for {path}")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    rate = Fraction(fps).limit_denominator(1001)
    with av.open(str(tmp), mode="w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=rate, options=dict(H264_OPTIONS))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        # Fixed container metadata: no creation time, so equal frames give equal bytes.
        container.metadata["encoder"] = "visphy"
        for frame in frames:
            if frame.shape != (height, width, 3):
                raise ValueError(f"frame shape {frame.shape} differs from {(height, width, 3)}")
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    os.replace(tmp, path)
    return path


def decode_video(path: str | Path) -> tuple[np.ndarray, ClipInfo]:
    """Decode every frame of a clip to RGB uint8 (N×H×W×3) with its fps and size."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video not found: {path}")
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            fps = float(stream.average_rate or stream.base_rate or 0) or 0.0
            frames = [f.to_ndarray(format="rgb24") for f in container.decode(stream)]
    except av.error.FFmpegError as exc:  # type: ignore[attr-defined]
        raise ValueError(f"cannot decode video {path}: {exc}") from exc
    if not frames:
        raise ValueError(f"video has no frames: {path}")
    arr = np.stack(frames)
    return arr, ClipInfo(fps=fps, n_frames=len(frames), width=arr.shape[2], height=arr.shape[1])


def resize_with_padding(frame: np.ndarray, width: int, height: int) -> np.ndarray:
    """Fit a frame into width×height keeping its aspect ratio, padding with white."""
    from PIL import Image

    h, w = frame.shape[:2]
    if (w, h) == (width, height):
        return frame
    scale = min(width / w, height / h)
    new_w, new_h = max(1, round(w * scale)), max(1, round(h * scale))
    img = Image.fromarray(frame).resize((new_w, new_h), Image.Resampling.BILINEAR)
    out = np.full((height, width, 3), 255, dtype=np.uint8)
    x0, y0 = (width - new_w) // 2, (height - new_h) // 2
    out[y0 : y0 + new_h, x0 : x0 + new_w] = np.asarray(img)
    return out


def normalise_clip(
    frames: np.ndarray, source_fps: float, target: ClipInfo
) -> np.ndarray:
    """Resample a clip in time (nearest frame by timestamp) and space to the reference contract.

    Frame k of the result shows the source frame nearest to time k / target.fps; a source shorter
    than the reference holds its last frame, so frame counts always match and no frame pair is
    invented by index between clips of different frame rates.
    """
    if len(frames) == 0:
        raise ValueError("cannot normalise an empty clip")
    src_fps = source_fps if source_fps > 0 else target.fps
    times = np.arange(target.n_frames) / target.fps
    idx = np.clip(np.rint(times * src_fps).astype(int), 0, len(frames) - 1)
    return np.stack([resize_with_padding(frames[i], target.width, target.height) for i in idx])
