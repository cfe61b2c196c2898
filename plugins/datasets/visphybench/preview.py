"""Look at a benchmark at a glance: a contact sheet of first frames and a short animated preview.

Both lay scenes out on the same grid: cells of ``thumb × thumb`` pixels, each with a label strip
of `LABEL_H` pixels underneath holding the scene id, separated (and framed) by `GAP` pixels of
grey. Thumbnails keep their clip's aspect ratio (white padding). Files are written atomically.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from visphy_core.api.media import encode_video, png_bytes, resize_with_padding
from visphy_core.api.storage import atomic_write

GAP = 2
LABEL_H = 14
BACKGROUND = (224, 224, 224)
LABEL_BG = (255, 255, 255)
LABEL_FG = (0, 0, 0)


def grid_layout(n: int, columns: int, thumb: int) -> tuple[int, int, int, int]:
    """(columns, rows, width, height) of a grid of ``n`` labelled cells."""
    if n <= 0:
        raise ValueError("a grid needs at least one scene")
    if columns <= 0 or thumb <= 0:
        raise ValueError(f"columns ({columns}) and thumb ({thumb}) must be positive")
    cols = min(columns, n)
    rows = math.ceil(n / cols)
    return cols, rows, cols * thumb + (cols + 1) * GAP, rows * (thumb + LABEL_H) + (rows + 1) * GAP


def cell_origin(index: int, cols: int, thumb: int) -> tuple[int, int]:
    """(x, y) of the top-left pixel of thumbnail ``index`` (row-major)."""
    row, col = divmod(index, cols)
    return GAP + col * (thumb + GAP), GAP + row * (thumb + LABEL_H + GAP)


def _rgb(frame: np.ndarray) -> np.ndarray:
    arr = np.asarray(frame)
    if arr.dtype != np.uint8:
        raise ValueError(f"frames must be uint8, got {arr.dtype}")
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    elif arr.ndim == 3 and arr.shape[2] == 4:
        arr = arr[:, :, :3]
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"frame of shape {arr.shape} is not H×W×3 RGB")
    return arr


def _label_canvas(ids: list[str], cols: int, rows: int, width: int, height: int,
                  thumb: int) -> np.ndarray:
    """The grid background with every cell's label strip drawn."""
    from PIL import Image, ImageDraw, ImageFont

    img = Image.new("RGB", (width, height), BACKGROUND)
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    for i, sid in enumerate(ids):
        x, y = cell_origin(i, cols, thumb)
        draw.rectangle([x, y + thumb, x + thumb - 1, y + thumb + LABEL_H - 1], fill=LABEL_BG)
        text = str(sid)
        while len(text) > 1 and draw.textlength(text, font=font) > thumb - 2:
            text = text[:-2] + "…"
        draw.text((x + 1, y + thumb + 1), text, fill=LABEL_FG, font=font)
    return np.asarray(img).copy()


def _paste(canvas: np.ndarray, index: int, cols: int, thumb: int, frame: np.ndarray) -> None:
    x, y = cell_origin(index, cols, thumb)
    canvas[y : y + thumb, x : x + thumb] = resize_with_padding(_rgb(frame), thumb, thumb)


def write_contact_sheet(first_frames: list[tuple[str, np.ndarray]], path: Path,
                        columns: int = 16, thumb: int = 96) -> Path:
    """PNG grid of first frames (row-major, ``min(columns, n)`` per row), each labelled."""

    path = Path(path)
    ids = [sid for sid, _ in first_frames]
    cols, rows, width, height = grid_layout(len(first_frames), columns, thumb)
    canvas = _label_canvas(ids, cols, rows, width, height, thumb)
    for i, (_, frame) in enumerate(first_frames):
        _paste(canvas, i, cols, thumb, frame)
    return atomic_write(path, png_bytes(canvas))


def resample_indices(n_source: int, n_target: int) -> np.ndarray:
    """Source frame nearest in time to each of ``n_target`` frames spanning the same duration."""
    if n_source <= 0 or n_target <= 0:
        raise ValueError(f"cannot resample {n_source} frames to {n_target}")
    if n_target == 1:
        return np.zeros(1, dtype=int)
    pos = np.arange(n_target) * (n_source - 1) / (n_target - 1)
    return np.clip(np.floor(pos + 0.5).astype(int), 0, n_source - 1)


def write_preview(clips: list[tuple[str, np.ndarray]], path: Path, fps: float = 5,
                  thumb: int = 128, max_scenes: int = 16, *,
                  n_frames: int | None = None) -> Path:
    """Animated MP4 grid of the first ``max_scenes`` clips, playing together.

    Every clip is resampled to a common frame count (``n_frames``; default: the shortest clip's)
    by taking, for each output frame, the source frame nearest in time when each clip spans the
    preview's whole duration — so a 2D clip (17 frames @ 5 fps) and a 3D clip (75 @ 15 fps) start
    and end together. The grid is ``ceil(sqrt(n))`` cells wide, padded to even dimensions.
    """
    clips = list(clips)[:max_scenes]
    if not clips:
        raise ValueError(f"no clip to preview in {path}")
    lengths = [len(frames) for _, frames in clips]
    if min(lengths) == 0:
        empty = [sid for sid, frames in clips if len(frames) == 0]
        raise ValueError(f"empty clip(s) {', '.join(map(str, empty))} for preview {path}")
    n_out = int(n_frames) if n_frames is not None else min(lengths)
    cols, rows, width, height = grid_layout(len(clips), math.ceil(math.sqrt(len(clips))), thumb)
    base = _label_canvas([sid for sid, _ in clips], cols, rows, width, height, thumb)
    pad_w, pad_h = width % 2, height % 2
    if pad_w or pad_h:
        base = np.pad(base, ((0, pad_h), (0, pad_w), (0, 0)), constant_values=BACKGROUND[0])
    # Thumbnails per clip, only for the frames actually used.
    thumbs = []
    for _, frames in clips:
        idx = resample_indices(len(frames), n_out)
        cache = {i: resize_with_padding(_rgb(frames[i]), thumb, thumb) for i in set(idx.tolist())}
        thumbs.append([cache[i] for i in idx.tolist()])
    out = np.empty((n_out, *base.shape), dtype=np.uint8)
    for k in range(n_out):
        out[k] = base
        for i in range(len(clips)):
            x, y = cell_origin(i, cols, thumb)
            out[k, y : y + thumb, x : x + thumb] = thumbs[i][k]
    return encode_video(out, Path(path), fps)
