"""Clips and images copied into a report folder, so the folder works on its own from disk.

A clip is copied byte for byte when Chromium shows it faithfully: H.264 (or VP8/VP9/AV1) in
4:2:0 chroma. Anything else is transcoded for the report only, to H.264 yuv420p. The case that
matters is the lossless ground truth (``libx264rgb``: H.264 *High 4:4:4 Predictive*, planar
GBR): Chromium plays it without complaint but reads the planes as YUV, so a red (200, 50, 100)
shows as (154, 0, 0). The report says where a clip was transcoded; scores always use the
original files.

Copies are idempotent: a file already in place from the same source (size and modification
time recorded in ``media/.sources.json``) is neither copied nor transcoded again.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Codecs and pixel formats Chromium decodes with the right colours.
PLAYABLE_CODECS = {"h264", "vp8", "vp9", "av1"}
PLAYABLE_PIX_FMTS = {"yuv420p", "yuvj420p"}
#: Encoder options of the report's transcodes.
BROWSER_H264 = {"crf": "18", "preset": "veryfast", "tune": "animation", "threads": "1"}
#: Index of what each copied file was made from.
SOURCES = ".sources.json"


def file_stamp(path: Path) -> str:
    """What a cached entry made from ``path`` was made from: its resolved path, size and
    modification time."""
    st = path.stat()
    return f"{path.resolve()}:{st.st_size}:{st.st_mtime_ns}"


def read_index(path: Path) -> dict:
    """A report folder's JSON index (``media/.sources.json``, ``media/.plots.json``); empty when
    absent or unreadable."""
    try:
        return json.loads(path.read_text()) if path.is_file() else {}
    except ValueError:
        return {}


def write_index(path: Path, text: str) -> None:
    """Replace the index at ``path`` with ``text`` atomically, unless it already says that."""
    if path.is_file() and path.read_text() == text:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


@dataclass
class Placed:
    """A file of the report folder: ``rel`` is its path from the report's ``index.html``."""

    rel: str | None
    note: str | None = None    # how it was made, when not a plain copy
    error: str | None = None   # why there is no file


def describe_clip(path: Path) -> tuple[bool, str]:
    """Whether Chromium shows ``path`` faithfully, and what the clip is (codec, profile,
    pixel format)."""
    import av

    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            ctx = stream.codec_context
            codec, pix_fmt = ctx.name, ctx.pix_fmt or "?"
            profile = ctx.profile or ""
    except (av.error.FFmpegError, IndexError, OSError) as exc:  # type: ignore[attr-defined]
        return False, f"unreadable ({type(exc).__name__}: {exc})"
    what = " ".join(p for p in (codec.upper() if codec == "h264" else codec, profile,
                                f"({pix_fmt})") if p)
    return codec in PLAYABLE_CODECS and pix_fmt in PLAYABLE_PIX_FMTS, what


def clip_timing(path: Path) -> tuple[float, int]:
    """fps and frame count of a clip from its header (0, 0 when unreadable)."""
    import av

    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            return float(stream.average_rate or 0), int(stream.frames or 0)
    except (av.error.FFmpegError, IndexError, OSError):  # type: ignore[attr-defined]
        return 0.0, 0


def _even(frames: np.ndarray) -> np.ndarray:
    """Edge-pad odd heights/widths by one pixel (4:2:0 needs even sizes)."""
    pad_h, pad_w = frames.shape[1] % 2, frames.shape[2] % 2
    if pad_h or pad_w:
        frames = np.pad(frames, ((0, 0), (0, pad_h), (0, pad_w), (0, 0)), mode="edge")
    return frames


def av_errors() -> type[BaseException]:
    import av

    return av.error.FFmpegError  # type: ignore[attr-defined]


def encode_for_browser(frames: np.ndarray, dest: Path, fps: float) -> None:
    """H.264 yuv420p at crf 18, preset ``veryfast`` (a quarter of the time of visphy's archival
    encoding, `visphy_core.infra.video.encode_video`; this copy is only looked at), atomically."""
    from fractions import Fraction

    import av

    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.tmp")
    with av.open(str(tmp), mode="w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001),
                                      options=BROWSER_H264)
        stream.width, stream.height = frames.shape[2], frames.shape[1]
        stream.pix_fmt = "yuv420p"
        for frame in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    os.replace(tmp, dest)


class MediaStore:
    """Places files under ``<report_dir>/media`` and remembers where each came from."""

    def __init__(self, report_dir: Path):
        self.report_dir = Path(report_dir)
        self.media = self.report_dir / "media"
        self.sources: dict[str, dict] = read_index(self.media / SOURCES)
        self.used: set[str] = set()
        self._decoded: tuple[Path, np.ndarray, float] | None = None

    def _decode(self, path: Path) -> tuple[np.ndarray, float]:
        """Decoded frames and fps of ``path``; the last clip is kept (its key frames and its
        transcode read it once)."""
        from visphy_core.infra.video import decode_video

        if self._decoded is None or self._decoded[0] != path:
            frames, info = decode_video(path)
            self._decoded = (path, frames, info.fps)
        return self._decoded[1], self._decoded[2]

    def _fresh(self, rel: str, stamp: str) -> dict | None:
        entry = self.sources.get(rel)
        if entry and entry.get("stamp") == stamp and (self.report_dir / rel).is_file():
            return entry
        return None

    def _remember(self, rel: str, stamp: str, note: str | None) -> Placed:
        self.sources[rel] = {"stamp": stamp, "note": note}
        self.used.add(rel)
        return Placed(rel, note)

    def video(self, src: Path | None, rel: str) -> Placed:
        """Copy (or transcode) clip ``src`` to ``rel``."""
        if src is None or not src.is_file():
            return Placed(None, error=f"no file {src}" if src else "no clip")
        stamp = file_stamp(src)
        entry = self._fresh(rel, stamp)
        if entry is not None:
            self.used.add(rel)
            return Placed(rel, entry.get("note"))
        dest = self.report_dir / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        playable, what = describe_clip(src)
        if playable:
            try:
                shutil.copyfile(src, dest)
            except OSError as exc:
                return Placed(None, error=f"cannot copy {src}: {exc}")
            return self._remember(rel, stamp, None)
        try:
            frames, fps = self._decode(src)
            encode_for_browser(_even(frames), dest, fps or 5.0)
        except (ValueError, OSError, av_errors()) as exc:
            return Placed(None, error=f"cannot show {src.name}: {what}: {exc}")
        note = (f"transcoded for the browser from {what} to H.264 yuv420p (Chromium does not "
                "show the original faithfully); scores use the original clip")
        return self._remember(rel, stamp, note)

    def image(self, src: Path, rel: str) -> Placed:
        """Copy image ``src`` to ``rel``."""
        if not src.is_file():
            return Placed(None, error=f"no file {src}")
        stamp = file_stamp(src)
        if self._fresh(rel, stamp) is None:
            (self.report_dir / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, self.report_dir / rel)
            return self._remember(rel, stamp, None)
        self.used.add(rel)
        return Placed(rel)

    def frame_of(self, video: Path, index: int, rel: str) -> Placed:
        """Frame ``index`` (1-based) of ``video`` as a PNG at ``rel`` (a key frame the dataset
        keeps no image of)."""
        if not video.is_file():
            return Placed(None, error=f"no file {video}")
        stamp = f"{file_stamp(video)}#frame{index}"
        if self._fresh(rel, stamp) is None:
            from PIL import Image

            try:
                frames, _ = self._decode(video)
            except (ValueError, OSError) as exc:
                return Placed(None, error=str(exc))
            if not 1 <= index <= len(frames):
                return Placed(None, error=f"{video.name} has {len(frames)} frames, no frame "
                                          f"{index}")
            (self.report_dir / rel).parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(frames[index - 1]).save(self.report_dir / rel)
            return self._remember(rel, stamp, f"frame {index} decoded from the ground-truth clip")
        self.used.add(rel)
        return Placed(rel, self.sources[rel].get("note"))

    def close(self) -> None:
        """Drop files of earlier reports that this one no longer shows; save the index."""
        for rel in list(self.sources):
            if rel not in self.used:
                try:
                    (self.report_dir / rel).unlink()
                except OSError:
                    pass
                del self.sources[rel]
        if self.sources or self.media.is_dir():
            write_index(self.media / SOURCES, json.dumps(self.sources, indent=1, sort_keys=True))
