"""Videos for the rating page: browser-playable copies and HTTP byte ranges.

Browsers seek and loop an MP4 through range requests, so the server answers ``Range: bytes=…``
with ``206 Partial Content``. Every clip visphy writes is H.264 yuv420p, which every browser
plays; a lossless ground truth (``libx264rgb``, 4:4:4) is not playable everywhere, so such a clip
is served as an H.264 yuv420p copy made on first request (kept for the server's lifetime).
"""

from __future__ import annotations

import hashlib
import re
import threading
from pathlib import Path

import av

RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


def is_playable(path: Path) -> bool:
    """H.264 in yuv420p: what every browser decodes."""
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            return stream.codec_context.name == "h264" and stream.codec_context.pix_fmt \
                == "yuv420p"
    except (av.error.FFmpegError, IndexError, OSError):
        return False


class PlayableCopies:
    """Maps a clip to a file a browser can play: the clip itself or a yuv420p copy in
    ``folder`` (made once per clip, one clip at a time)."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self._lock = threading.Lock()
        self._known: dict[Path, Path] = {}

    def get(self, path: Path) -> Path:
        path = Path(path)
        with self._lock:
            if path not in self._known:
                self._known[path] = path if is_playable(path) else self._transcode(path)
            return self._known[path]

    def _transcode(self, path: Path) -> Path:
        from visphy_core.infra.video import decode_video, encode_video

        frames, info = decode_video(path)
        out = self.folder / (hashlib.sha256(str(path).encode()).hexdigest()[:16] + ".mp4")
        return encode_video(frames, out, info.fps)


def byte_range(header: str | None, size: int) -> tuple[int, int] | None:
    """The inclusive (start, end) a ``Range`` header asks for; None for the whole file.
    ``ValueError`` when it cannot be satisfied (the caller answers 416)."""
    if not header:
        return None
    match = RANGE.match(header.strip())
    if not match or not (match.group(1) or match.group(2)):
        raise ValueError(f"unsupported range {header!r}")
    first, last = match.groups()
    if first == "":  # the last N bytes
        start, end = max(0, size - int(last)), size - 1
    else:
        start, end = int(first), min(size - 1, int(last)) if last else size - 1
    if start > end or start >= size:
        raise ValueError(f"range {header!r} outside a file of {size} bytes")
    return start, end
