"""The one PNG codec (Pillow, default settings: the same frame always gives the same bytes)."""

from __future__ import annotations

import io

import numpy as np


def png_bytes(frame: np.ndarray) -> bytes:
    """PNG bytes of an H×W×3 (or H×W×4) uint8 frame."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(frame, dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def decode_png(data: bytes, background: tuple[int, int, int] | None = None) -> np.ndarray:
    """RGB uint8 H×W×3 from PNG (or any Pillow-readable) bytes. With ``background``,
    transparent pixels are composited over that colour (a canvas' transparent pixels show the
    page behind them); without it the alpha channel is dropped."""
    from PIL import Image

    with Image.open(io.BytesIO(data)) as img:
        img.load()
        if background is not None:
            rgba = img if img.mode == "RGBA" else img.convert("RGBA")
            under = Image.new("RGBA", rgba.size, (*background, 255))
            return np.asarray(Image.alpha_composite(under, rgba).convert("RGB"))
        return np.asarray(img.convert("RGB"), dtype=np.uint8).copy()
