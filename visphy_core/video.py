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


#: The published VisPhyBench clips' encoding: H.264 yuv420p at crf 23.
PUBLISHED_CRF = 23


def encode_video(frames: np.ndarray | list[np.ndarray], path: str | Path, fps: float,
                 crf: int | None = None, lossless: bool = False) -> Path:
    """Write RGB uint8 frames (N×H×W×3) to an H.264 MP4 atomically (temp file, then rename).
    ``crf`` overrides `H264_OPTIONS`' (visphy's own clips: 12); ``lossless``: H.264 in RGB
    (libx264rgb, crf 0), whose frames decode back bit for bit."""
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
        options = dict(H264_OPTIONS) | ({"crf": str(crf)} if crf is not None else {})
        if lossless:
            options["crf"] = "0"
        stream = container.add_stream("libx264rgb" if lossless else "libx264", rate=rate,
                                      options=options)
        stream.width, stream.height = width, height
        stream.pix_fmt = "rgb24" if lossless else "yuv420p"
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


#: A source frame counts as shown at time t when its timestamp is at most t plus this much:
#: container time bases round timestamps (1/17920 s for 35 fps in MP4), so a frame meant for
#: exactly t may carry a timestamp a few microseconds after it.
TIME_TOLERANCE_S = 0.0005


def decode_video_timed(path: str | Path) -> tuple[np.ndarray, np.ndarray, ClipInfo]:
    """Decode a clip with each frame's presentation time in seconds, the first frame at 0.

    Times come from each frame's PTS × time base, so variable frame rates and a non-zero start
    time (the first PTS is subtracted) are honoured; a frame without a PTS gets index / fps.
    Frames are returned in presentation order.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video not found: {path}")
    frames: list[np.ndarray] = []
    stamps: list[float | None] = []
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            fps = float(stream.average_rate or stream.base_rate or 0) or 0.0
            for frame in container.decode(stream):
                frames.append(frame.to_ndarray(format="rgb24"))
                base = frame.time_base or stream.time_base
                stamps.append(float(frame.pts * base) if frame.pts is not None and base
                              else None)
    except av.error.FFmpegError as exc:  # type: ignore[attr-defined]
        raise ValueError(f"cannot decode video {path}: {exc}") from exc
    if not frames:
        raise ValueError(f"video has no frames: {path}")
    if any(s is None for s in stamps):
        if fps <= 0:
            raise ValueError(f"video {path} has frames without timestamps and no frame rate")
        times = np.arange(len(frames), dtype=np.float64) / fps
    else:
        times = np.asarray(stamps, dtype=np.float64)
        order = np.argsort(times, kind="stable")
        if np.any(order != np.arange(len(order))):
            frames = [frames[i] for i in order]
            times = times[order]
        times = times - times[0]
    arr = np.stack(frames)
    if fps <= 0 and len(times) > 1 and times[-1] > 0:
        fps = (len(times) - 1) / float(times[-1])
    return arr, times, ClipInfo(fps=fps, n_frames=len(frames), width=arr.shape[2],
                                height=arr.shape[1])


def shown_at(times_s: np.ndarray, target_times_s: np.ndarray) -> np.ndarray:
    """Index of the source frame on screen at each target time: the last one whose timestamp
    is at most t (+ `TIME_TOLERANCE_S`); the first frame before the clip starts, the last frame
    held after it ends."""
    times_s = np.asarray(times_s, dtype=np.float64)
    if len(times_s) == 0:
        raise ValueError("cannot resample an empty clip")
    idx = np.searchsorted(times_s, np.asarray(target_times_s) + TIME_TOLERANCE_S,
                          side="right") - 1
    return np.clip(idx, 0, len(times_s) - 1)


def resample_by_time(frames: np.ndarray, times_s: np.ndarray, target: ClipInfo) -> np.ndarray:
    """The clip ``target`` describes, cut from ``frames`` shown at ``times_s`` (seconds).

    Frame k of the result is the source frame shown at time k / target.fps (see `shown_at`),
    fitted into target.width×target.height with `resize_with_padding`.
    """
    if len(frames) == 0:
        raise ValueError("cannot resample an empty clip")
    if len(times_s) != len(frames):
        raise ValueError(f"{len(frames)} frames but {len(times_s)} timestamps")
    if target.fps <= 0 or target.n_frames <= 0:
        raise ValueError(f"bad target clip {target}")
    idx = shown_at(times_s, np.arange(target.n_frames) / target.fps)
    return np.stack([resize_with_padding(frames[i], target.width, target.height) for i in idx])


def clip_matches(info: ClipInfo, target: ClipInfo, rel_tol: float = 1e-3) -> bool:
    """Whether a clip already meets ``target``: same frame count and size, fps within 0.1 %."""
    return (info.n_frames == target.n_frames and (info.width, info.height)
            == (target.width, target.height)
            and abs(info.fps - target.fps) <= rel_tol * max(target.fps, 1e-9))


def load_clip_for(path: str | Path, target: ClipInfo) -> np.ndarray:
    """A foreign clip as the frames ``target`` describes, paired with the reference by time.

    A clip that already meets the contract comes back exactly as decoded.
    """
    frames, times, info = decode_video_timed(path)
    if clip_matches(info, target):
        return frames
    return resample_by_time(frames, times, target)


def normalise_clip(
    frames: np.ndarray, source_fps: float, target: ClipInfo
) -> np.ndarray:
    """Resample a constant-rate clip (frame i at i / source_fps) in time and space to ``target``.

    The same rule as `resample_by_time`: frame k of the result is the source frame shown at
    k / target.fps; a source shorter than the reference holds its last frame. For a decoded file
    prefer `load_clip_for`, which uses the file's own timestamps.
    """
    if len(frames) == 0:
        raise ValueError("cannot normalise an empty clip")
    if source_fps <= 0:
        raise ValueError(f"source fps must be positive, got {source_fps}")
    return resample_by_time(frames, np.arange(len(frames)) / source_fps, target)
