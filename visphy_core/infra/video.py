"""Video I/O with PyAV: deterministic H.264 encoding, decoding, normalisation, frame hashing.

Everything that reads or writes a clip goes through here, so the reference clip and the generated
clip are encoded and decoded the same way before they are compared.

**Untrusted media.** Frames and videos that come from outside visphy's own code (files a
sandboxed program could have rewritten, a model's or provider's video) are read only through the
budgeted readers at the end of this module: `read_untrusted_frames` (an engine's PNG frames),
`read_untrusted_raw_frames` (an engine's raw RGB frames), `decode_video_timed` with a
`VideoBudget` and `load_clip_for` (a model's clip). Each checks what the file's header promises
(PNG IHDR; the container's stream size, frame count, duration) against the caller's contract or
budget before decoding anything, never follows a symbolic link, caps the file size, re-checks every
decoded frame, and stops at a wall-clock deadline (`DeadlineExceeded`). Refusals are
`FrameRejected` (a ValueError) whose message names the file and the reason. Ground-truth clips
(visphy's own files) keep the plain `decode_video` / `decode_video_timed`.
"""
# size: every clip read and write, trusted and untrusted, in one place

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterator, Sequence

import av
import numpy as np

from visphy_core.infra.png import (
    DeadlineExceeded,
    FrameRejected,
    open_untrusted,
    read_untrusted_png,
)

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


#: The paper's published benchmark clips' encoding: H.264 yuv420p at crf 23.
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


def decode_video_timed(path: str | Path, budget: "VideoBudget | None" = None
                       ) -> tuple[np.ndarray, np.ndarray, ClipInfo]:
    """Decode a clip with each frame's presentation time in seconds, the first frame at 0.

    Times come from each frame's PTS × time base, so variable frame rates and a non-zero start
    time (the first PTS is subtracted) are honoured; a frame without a PTS gets index / fps.
    Frames are returned in presentation order.

    With ``budget`` the file is untrusted (a provider's or model's video): see
    `decode_untrusted_video_timed`. Without it (visphy's own clips) it is decoded as is.
    """
    if budget is not None:
        return decode_untrusted_video_timed(path, budget)
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
    return _timed(path, frames, stamps, fps)


def _timed(path: Path, frames: list[np.ndarray], stamps: list[float | None], fps: float
           ) -> tuple[np.ndarray, np.ndarray, ClipInfo]:
    """`decode_video_timed`'s result from decoded frames and their timestamps (None: none)."""
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


def load_clip_for(path: str | Path, target: ClipInfo,
                  budget: "VideoBudget | None" = None,
                  keep_decoded: list | None = None, keep_max: int = 0) -> np.ndarray:
    """A foreign clip (a model's video: untrusted) as the frames ``target`` describes, paired
    with the reference by time (the same rule as `resample_by_time`).

    A clip that already meets the contract comes back exactly as decoded. The file is read
    under ``budget`` (default `VideoBudget()`): its header is checked before any frame is
    decoded, and the frames are fitted to the target as they are decoded, so memory stays at
    one target-sized clip whatever the source's size or frame count (see `stream_clip_for`).
    ``keep_decoded``/``keep_max``: see `stream_clip_for` (the paper protocol's clip by index).
    """
    return stream_clip_for(path, target, budget or VideoBudget(), keep_decoded, keep_max)


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


# ------------------------------------------------------------------------------ untrusted media
#: Default limits of a foreign (model- or provider-made) video, checked on the container header
#: before decoding and again on every decoded frame.
@dataclass(frozen=True)
class VideoBudget:
    """What decoding an untrusted video may cost.

    ``size``: the exact (width, height) every frame must have (an engine's render contract);
    None accepts any size within ``max_side`` / ``max_frame_pixels``. ``max_frames`` /
    ``max_seconds``: the frame count and duration the header may announce and the decoder may
    deliver. ``max_total_pixels``: pixels decoded in all (the CPU and, for
    `decode_untrusted_video_timed`, the memory a clip may take: 3 bytes each).
    ``deadline``: a `time.monotonic` instant after which decoding stops with
    `DeadlineExceeded` (an engine passes its render's wall-clock deadline).
    """

    size: tuple[int, int] | None = None
    max_side: int = 8192
    max_frame_pixels: int = 8192 * 4352         # 8K UHD (7680×4320) fits
    max_frames: int = 20_000
    max_seconds: float = 600.0
    max_total_pixels: int = 1_000_000_000       # 3 GB of RGB when every frame is kept
    max_bytes: int = 2 << 30
    deadline: float | None = None


def _check_deadline(deadline: float | None, what: str) -> None:
    if deadline is not None and time.monotonic() > deadline:
        raise DeadlineExceeded(what)


def read_untrusted_frames(paths: Sequence[str | os.PathLike], width: int, height: int,
                          max_frames: int, deadline: float | None = None) -> np.ndarray:
    """Untrusted PNG frames (files a sandboxed program could have rewritten) as N×H×W×3 uint8.

    At most ``max_frames`` files (the contract's frame count; more is `FrameRejected`); each is
    read by `visphy_core.infra.png.read_untrusted_png`: no symbolic links, regular files only, a
    size cap, and its header must say exactly ``width×height`` before it is decoded. The clip's
    memory is allocated once, at the contract size. ``deadline`` (`time.monotonic`) is checked
    before every frame: past it, `DeadlineExceeded` says how far reading got.
    """
    if len(paths) > max_frames:
        raise FrameRejected(f"{len(paths)} frame files, more than the clip's {max_frames}: "
                            "refused")
    out = np.empty((len(paths), height, width, 3), dtype=np.uint8)
    for k, path in enumerate(paths):
        _check_deadline(deadline, f"frame {k} of {len(paths)} was not read yet")
        out[k] = read_untrusted_png(path, width, height)
    return out


def read_untrusted_raw_frames(path: str | os.PathLike, width: int, height: int,
                              max_frames: int, deadline: float | None = None) -> np.ndarray:
    """Untrusted raw RGB frames (``width×height×3`` bytes each, frame after frame) as
    count×H×W×3 uint8: no symbolic link, a regular file, at most ``max_frames`` frames' bytes
    (checked on its size before reading), a whole number of frames; read straight into the
    result (one copy), checking ``deadline`` every 16 MiB."""
    name = Path(path).name
    frame_bytes = width * height * 3
    cap = max_frames * frame_bytes
    fd, size = open_untrusted(path, cap, f"the clip's {max_frames} frames of {width}x{height} "
                                         f"px ({cap} bytes)")
    with os.fdopen(fd, "rb", buffering=0) as f:
        if size % frame_bytes:
            raise FrameRejected(f"{name} is {size} bytes, not a whole number of "
                                f"{width}x{height} RGB frames ({frame_bytes} bytes each)")
        count = size // frame_bytes
        out = np.empty((count, height, width, 3), dtype=np.uint8)
        view = memoryview(out.reshape(-1))
        done = 0
        while done < size:
            _check_deadline(deadline, f"{done} of {size} bytes of {name} were read")
            got = f.readinto(view[done:min(size, done + (16 << 20))])
            if not got:
                raise FrameRejected(f"{name} shrank while it was read ({done} of {size} bytes)")
            done += got
    return out


def _check_video_size(name: str, width: int, height: int, budget: VideoBudget,
                      when: str = "before decoding") -> None:
    if not width or not height:
        raise FrameRejected(f"{name}: the video header gives no frame size: refused")
    if budget.size is not None and (width, height) != tuple(budget.size):
        raise FrameRejected(f"{name} is {width}x{height} px, not the clip's "
                            f"{budget.size[0]}x{budget.size[1]}: refused {when}")
    if max(width, height) > budget.max_side or width * height > budget.max_frame_pixels:
        raise FrameRejected(f"{name} is {width}x{height} px, beyond the decoding budget "
                            f"({budget.max_side} px a side, {budget.max_frame_pixels} pixels a "
                            f"frame): refused {when}")


#: ISO-BMFF top-level box types a real MP4/MOV starts with.
_BMFF_BOXES = (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip", b"pnot")


def _container_format(head: bytes) -> str | None:
    """The FFmpeg demuxer for a file's first bytes: ``mp4`` (MP4/MOV), ``matroska``
    (Matroska/WebM), else None."""
    if len(head) >= 8 and head[4:8] in _BMFF_BOXES:
        return "mp4"
    if head[:4] == b"\x1a\x45\xdf\xa3":
        return "matroska"
    return None


class _UntrustedVideo:
    """An untrusted video opened without following links, its header checked against a budget
    (stream size, announced frame count and duration) before any frame is decoded."""

    def __init__(self, path: str | os.PathLike, budget: VideoBudget):
        self.name = Path(path).name
        self.budget = budget
        fd, _ = open_untrusted(path, budget.max_bytes)
        self.file = os.fdopen(fd, "rb")
        try:
            demuxer = _container_format(self.file.read(12))
            if demuxer is None:
                raise FrameRejected(f"{self.name} is not an MP4/MOV or Matroska/WebM video: "
                                    "refused")
            self.file.seek(0)
            # the demuxer is named: FFmpeg's probing never picks a playlist or image2 demuxer
            # (HLS/concat open further files or URLs), whatever the bytes look like
            self.container = av.open(self.file, mode="r", format=demuxer)
        except FrameRejected:
            self.file.close()
            raise
        except Exception as exc:  # noqa: BLE001 - whatever FFmpeg says about the bytes
            self.file.close()
            raise FrameRejected(f"{self.name} is not a readable video: {str(exc)[:200]}") from None
        try:
            self._check_header()
        except BaseException:
            self.close()
            raise

    def _check_header(self) -> None:
        c, b, name = self.container, self.budget, self.name
        if not c.streams.video:
            raise FrameRejected(f"{name} has no video stream")
        s = self.stream = c.streams.video[0]
        _check_video_size(name, int(s.codec_context.width or 0),
                          int(s.codec_context.height or 0), b)
        if (s.frames or 0) > b.max_frames:
            raise FrameRejected(f"{name} announces {s.frames} frames, more than the "
                                f"{b.max_frames} allowed: refused before decoding")
        seconds = None
        if s.duration and s.time_base:
            seconds = float(s.duration * s.time_base)
        elif c.duration:
            seconds = c.duration / av.time_base
        if seconds is not None and seconds > b.max_seconds:
            raise FrameRejected(f"{name} announces {seconds:g} s, more than the "
                                f"{b.max_seconds:g} s allowed: refused before decoding")
        self.fps = float(s.average_rate or s.base_rate or 0) or 0.0

    def frames(self) -> Iterator["av.VideoFrame"]:
        """Decoded frames, each checked (size, count, pixels decoded, deadline)."""
        b, name = self.budget, self.name
        count = pixels = 0
        try:
            for frame in self.container.decode(self.stream):
                _check_deadline(b.deadline, f"{count} frames of {name} were decoded")
                _check_video_size(name, frame.width, frame.height, b, when="(a decoded frame)")
                count += 1
                pixels += frame.width * frame.height
                if count > b.max_frames:
                    raise FrameRejected(f"{name} has more than {b.max_frames} frames: refused")
                if pixels > b.max_total_pixels:
                    raise FrameRejected(f"{name} needs more than {b.max_total_pixels} decoded "
                                        f"pixels (at frame {count}): refused")
                yield frame
        except av.error.FFmpegError as exc:  # type: ignore[attr-defined]
            raise FrameRejected(f"cannot decode video {name}: {exc}") from None

    def stamp(self, frame: "av.VideoFrame") -> float | None:
        base = frame.time_base or self.stream.time_base
        return float(frame.pts * base) if frame.pts is not None and base else None

    def close(self) -> None:
        try:
            self.container.close()
        finally:
            self.file.close()

    def __enter__(self) -> "_UntrustedVideo":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def probe_untrusted_video(path: str | os.PathLike, budget: VideoBudget) -> dict:
    """What an untrusted video's header says (width, height, announced frames, fps), after the
    header checks of ``budget``; nothing is decoded."""
    with _UntrustedVideo(path, budget) as video:
        s = video.stream
        return {"width": int(s.codec_context.width), "height": int(s.codec_context.height),
                "frames": int(s.frames or 0), "fps": video.fps}


def decode_untrusted_video_timed(path: str | os.PathLike, budget: VideoBudget
                                 ) -> tuple[np.ndarray, np.ndarray, ClipInfo]:
    """`decode_video_timed` for an untrusted file: header first (`VideoBudget`), every frame
    checked as it is decoded; refusals are `FrameRejected`, a passed deadline
    `DeadlineExceeded`. Every frame is kept at its own size: ``budget.max_total_pixels``
    bounds the memory (3 bytes a pixel)."""
    path = Path(path)
    frames: list[np.ndarray] = []
    stamps: list[float | None] = []
    with _UntrustedVideo(path, budget) as video:
        for frame in video.frames():
            frames.append(frame.to_ndarray(format="rgb24"))
            stamps.append(video.stamp(frame))
        fps = video.fps
    if frames and len({f.shape for f in frames}) > 1:
        raise FrameRejected(f"{path.name} changes its frame size mid-stream: refused")
    return _timed(path, frames, stamps, fps)


def stream_clip_for(path: str | os.PathLike, target: ClipInfo, budget: VideoBudget,
                    keep_decoded: list | None = None, keep_max: int = 0) -> np.ndarray:
    """`load_clip_for`'s clip, decoded under ``budget`` without keeping the source's frames.

    Frames are taken in decoding (= presentation) order with their times relative to the
    first; each target frame k is the last source frame whose time is at most
    k / fps + `TIME_TOLERANCE_S` (`shown_at`), fitted to the target size only when it is
    chosen. Decoding stops once a frame lies past the target's last time. Timestamps that go
    backwards, or frames without one mixed with stamped frames, are `FrameRejected` (the
    trusted `decode_video_timed` sorts them; an untrusted stream must be in order). A clip that
    already meets ``target`` (`clip_matches`) comes back exactly as decoded.

    ``keep_decoded`` (a list) also receives the first ``keep_max`` frames in decode order, each
    stretched to the target's size by area interpolation (no timestamps, no padding): the clip
    as upstream's evaluation reads it (the ``paper`` protocol pairs frames by index), bounded to
    the frames that protocol can pair.
    """
    path = Path(path)
    n = target.n_frames
    if target.fps <= 0 or n <= 0:
        raise ValueError(f"bad target clip {target}")
    limits = np.arange(n, dtype=np.float64) / target.fps + TIME_TOLERANCE_S
    out = np.empty((n, target.height, target.width, 3), dtype=np.uint8)
    filled = 0
    current = None            # the last frame seen (an av.VideoFrame), not yet placed
    exact: list[np.ndarray] | None = []   # the frames as decoded while the clip may match
    first: float | None = None
    by_index = False
    previous = -np.inf
    count = 0

    def place(frame, upto: int) -> None:
        nonlocal filled
        if upto > filled:
            rgb = resize_with_padding(frame.to_ndarray(format="rgb24"), target.width,
                                      target.height)
            out[filled:upto] = rgb
            filled = upto

    with _UntrustedVideo(path, budget) as video:
        fps = video.fps
        for frame in video.frames():
            stamp = video.stamp(frame)
            if count == 0:
                by_index = stamp is None
                if by_index and fps <= 0:
                    raise ValueError(f"video {path} has frames without timestamps and no "
                                     "frame rate")
                first = stamp
            elif (stamp is None) != by_index:
                raise FrameRejected(f"{path.name} mixes frames with and without timestamps: "
                                    "refused")
            t = count / fps if by_index else float(stamp) - float(first)
            if t < previous:
                raise FrameRejected(f"{path.name}: frame {count}'s timestamp goes backwards "
                                    f"({t:.6g} s after {previous:.6g} s): refused")
            previous = t
            if current is not None:
                place(current, int(np.searchsorted(limits, t, side="left")))
            current = frame
            count += 1
            if exact is not None:
                if count > n or (frame.width, frame.height) != (target.width, target.height):
                    exact = None
                else:
                    exact.append(frame.to_ndarray(format="rgb24"))
            keeping = keep_decoded is not None and len(keep_decoded) < keep_max
            if keeping:
                rgb = frame.to_ndarray(format="rgb24")
                if rgb.shape[:2] != (target.height, target.width):
                    import cv2

                    rgb = cv2.resize(rgb, (target.width, target.height),
                                     interpolation=cv2.INTER_AREA)
                keep_decoded.append(rgb)
            if filled >= n and exact is None and not keeping:  # nothing more to see
                break
    if current is None:
        raise ValueError(f"video has no frames: {path}")
    if exact is not None and len(exact) == n:
        info = ClipInfo(fps=fps, n_frames=n, width=target.width, height=target.height)
        if clip_matches(info, target):
            return np.stack(exact)
    place(current, n)
    return out
