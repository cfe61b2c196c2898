"""Frames as the page hands them back: raw pixels (run-length encoded or as they are) or PNG.

Why not PNG only: ``canvas.toDataURL`` encodes a PNG on the page's main thread (tens of ms for a
512² frame in SwiftShader) and the host decodes it again; reading the pixels and sending runs of
equal RGBA values costs a few ms and a few kB for the flat-coloured clips of the benchmark. The
page sends raw pixels only where they are exactly what the PNG would hold (fully opaque, 8-bit
sRGB, the canvas' own size; see ``virtual_time.js``), and a PNG otherwise, so both paths give
the same frames byte for byte.
"""

from __future__ import annotations

import base64

import cv2
import numpy as np

from visphy_core.infra.png import decode_png


class ReadbackError(ValueError):
    """A frame payload from the page that does not describe a whole frame."""


#: The largest frame a page may hand back (a canvas of 4096² px; the clip is 512²): a payload
#: claiming more is refused before anything is decoded or expanded (the page controls its
#: canvas size, and a 16384² canvas would cost the host a gigabyte per frame).
MAX_FRAME_PIXELS = 4096 * 4096


def png_data_url_to_rgb(data_url: str) -> np.ndarray:
    """RGB of a ``data:image/png;base64,...`` URL; transparent canvas pixels are shown as the
    white page behind them."""
    return decode_png(base64.b64decode(data_url.split(",", 1)[1]), background=(255, 255, 255),
                      max_pixels=MAX_FRAME_PIXELS)


def png_bytes_to_rgb(png: bytes) -> np.ndarray:
    """RGB of a PNG screenshot (always opaque)."""
    return decode_png(png, max_pixels=MAX_FRAME_PIXELS)


def raw_to_rgb(payload: dict) -> np.ndarray:
    """RGB (H×W×3 uint8) of a raw payload: ``runs`` (base64 of little-endian uint32 pairs
    count, RGBA) or ``raw`` (base64 of RGBA bytes), ``width``, ``height``, ``flipY`` (rows
    bottom first, as WebGL reads them)."""
    width, height = int(payload["width"]), int(payload["height"])
    n = width * height
    if not 0 < n <= MAX_FRAME_PIXELS or width <= 0 or height <= 0:
        raise ReadbackError(f"a {width}x{height} frame is outside the readback budget "
                            f"(at most {MAX_FRAME_PIXELS} pixels)")
    if "runs" in payload:
        runs = np.frombuffer(base64.b64decode(payload["runs"]), dtype="<u4")
        if runs.size % 2:
            raise ReadbackError("run-length payload has an odd number of words")
        counts, values = runs[0::2], runs[1::2]
        if int(counts.sum(dtype=np.int64)) != n:
            raise ReadbackError(f"runs cover {int(counts.sum(dtype=np.int64))} pixels, "
                                f"not {width}x{height}")
        rgba = np.repeat(values, counts).view(np.uint8)
    else:
        rgba = np.frombuffer(base64.b64decode(payload["raw"]), dtype=np.uint8)
        if rgba.size != 4 * n:
            raise ReadbackError(f"raw payload has {rgba.size} bytes, not {4 * n}")
    # OpenCV drops the alpha byte and flips the rows in one pass each (numpy's strided copy of
    # three bytes in four took 1.5 ms of the 1.6 ms a 512² frame cost; these take 0.15 ms).
    rgb = cv2.cvtColor(rgba.reshape(height, width, 4), cv2.COLOR_RGBA2RGB)
    return cv2.flip(rgb, 0) if payload.get("flipY") else rgb


def frame_from_capture(shot) -> np.ndarray | None:
    """The frame of one ``captureAt``/``captureRawAt`` answer, or None when the page had no
    canvas to read."""
    if not isinstance(shot, dict):
        return None
    if "runs" in shot or "raw" in shot:
        return raw_to_rgb(shot)
    png = shot.get("png")
    if not isinstance(png, str) or not png.startswith("data:image/png"):
        return None
    return png_data_url_to_rgb(png)
