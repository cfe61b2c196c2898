"""The one PNG codec (Pillow, default settings: the same frame always gives the same bytes), and
its header-first reader for untrusted frames.

Frames a sandboxed program could have touched (an engine that writes its frames as
``frames/frame_*.png``) are read with `read_untrusted_png`: the file is opened without following
links (a regular file only, at most `png_size_cap` bytes), its IHDR (width, height, bit depth,
colour type) is parsed from the first 33 bytes and checked against the size the caller expects
**before** anything is decompressed, so a 10000×10000 frame costs a 33-byte read, not 300 MB of
pixels. Only a header that matches is decoded, by Pillow's PNG plugin alone, into exactly that
many pixels.
"""

from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from visphy_core.infra import files

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Signature (8) + IHDR chunk (length 4, type 4, data 13, CRC 4).
PNG_HEADER_BYTES = 33
#: Valid (colour type -> (channels, allowed bit depths)) of the PNG specification.
_COLOUR_TYPES = {0: (1, (1, 2, 4, 8, 16)), 2: (3, (8, 16)), 3: (1, (1, 2, 4, 8)),
                 4: (2, (8, 16)), 6: (4, (8, 16))}
#: Room for ancillary chunks (text, ICC profile, ...) on top of the largest possible pixel data.
PNG_CHUNK_SLACK = 1 << 20


class FrameRejected(ValueError):
    """An untrusted frame (or video) refused before or instead of decoding; the message says
    why in words a user can act on."""


class DeadlineExceeded(TimeoutError):
    """Reading untrusted frames on the host went past the render's wall-clock deadline."""


def png_bytes(frame: np.ndarray) -> bytes:
    """PNG bytes of an H×W×3 (or H×W×4) uint8 frame."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(frame, dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def decode_png(data: bytes, background: tuple[int, int, int] | None = None,
               max_pixels: int | None = None) -> np.ndarray:
    """RGB uint8 H×W×3 from PNG (or any Pillow-readable) bytes. With ``background``,
    transparent pixels are composited over that colour (a canvas' transparent pixels show the
    page behind them); without it the alpha channel is dropped. With ``max_pixels`` (bytes that
    came from untrusted code, e.g. a browser canvas) the data must be a PNG whose header says at
    most that many pixels, else `FrameRejected` before anything is decompressed."""
    from PIL import Image

    if max_pixels is not None:
        header = parse_png_header(data[:PNG_HEADER_BYTES], "the image")
        if header.width * header.height > max_pixels:
            raise FrameRejected(f"the image is {header.width}x{header.height} px, more than the "
                                f"{max_pixels} pixels allowed: refused before decoding")
    with Image.open(io.BytesIO(data), formats=["PNG"] if max_pixels is not None else None) as img:
        img.load()
        if background is not None:
            rgba = img if img.mode == "RGBA" else img.convert("RGBA")
            under = Image.new("RGBA", rgba.size, (*background, 255))
            return np.asarray(Image.alpha_composite(under, rgba).convert("RGB"))
        return np.asarray(img.convert("RGB"), dtype=np.uint8).copy()


# ------------------------------------------------------------------------------ untrusted PNGs
@dataclass(frozen=True)
class PngHeader:
    """A PNG's IHDR: what decoding it would allocate, known before any decompression."""

    width: int
    height: int
    bit_depth: int
    colour_type: int
    interlaced: bool

    @property
    def channels(self) -> int:
        return _COLOUR_TYPES[self.colour_type][0]


def parse_png_header(head: bytes, name: str = "the frame") -> PngHeader:
    """The IHDR of PNG bytes (only the first `PNG_HEADER_BYTES` are looked at), or
    `FrameRejected` for anything that is not a well-formed PNG header."""
    if head[:8] != PNG_SIGNATURE[:len(head)]:
        raise FrameRejected(f"{name} is not a PNG file (no PNG signature)")
    if len(head) < PNG_HEADER_BYTES:
        raise FrameRejected(f"{name} is truncated ({len(head)} bytes: no complete PNG header)")
    length, kind = struct.unpack(">I4s", head[8:16])
    if kind != b"IHDR" or length != 13:
        raise FrameRejected(f"{name} is not a valid PNG (the first chunk is not IHDR)")
    width, height, depth, colour, compression, filt, interlace = struct.unpack(
        ">IIBBBBB", head[16:29])
    valid = _COLOUR_TYPES.get(colour)
    if (width == 0 or height == 0 or valid is None or depth not in valid[1] or compression
            or filt or interlace > 1):
        raise FrameRejected(f"{name} has an invalid PNG header ({width}x{height} px, bit depth "
                            f"{depth}, colour type {colour})")
    return PngHeader(width, height, depth, colour, bool(interlace))


def png_size_cap(width: int, height: int) -> int:
    """The most bytes a width×height PNG can reasonably need: its pixels stored uncompressed at
    the widest format (16-bit RGBA, one filter byte per row), plus `PNG_CHUNK_SLACK`."""
    return height * (1 + width * 8) + PNG_CHUNK_SLACK


def _refuse_size(name: str, header: PngHeader, width: int, height: int) -> None:
    if (header.width, header.height) != (width, height):
        raise FrameRejected(f"{name} is {header.width}x{header.height} px, not the clip's "
                            f"{width}x{height}: refused before decoding")


def decode_untrusted_png(data: bytes, width: int, height: int,
                         name: str = "the frame") -> np.ndarray:
    """RGB uint8 ``height×width×3`` from untrusted PNG bytes whose header must say exactly
    ``width×height``; anything else is `FrameRejected` before decompression. Decoding uses
    Pillow's PNG plugin only, into an image of that (already checked) size."""
    from PIL import Image

    header = parse_png_header(data[:PNG_HEADER_BYTES], name)
    _refuse_size(name, header, width, height)
    if len(data) > png_size_cap(width, height):
        raise FrameRejected(f"{name} is {len(data)} bytes, more than a {width}x{height} PNG can "
                            f"need ({png_size_cap(width, height)}): refused")
    try:
        with Image.open(io.BytesIO(data), formats=["PNG"]) as img:
            if img.size != (width, height):  # Pillow's own reading of the header agrees
                raise FrameRejected(f"{name} is {img.size[0]}x{img.size[1]} px, not the "
                                    f"clip's {width}x{height}: refused before decoding")
            img.load()
            rgb = img if img.mode == "RGB" else img.convert("RGB")
            arr = np.asarray(rgb, dtype=np.uint8)
    except FrameRejected:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever Pillow says about broken data
        raise FrameRejected(f"{name} does not decode: {type(exc).__name__}: "
                            f"{str(exc)[:200]}") from None
    if arr.shape != (height, width, 3):
        raise FrameRejected(f"{name} decoded to {arr.shape}, not ({height}, {width}, 3)")
    return arr


def open_untrusted(path: str | os.PathLike, max_bytes: int,
                   allowed: str | None = None) -> tuple[int, int]:
    """(fd, size) of a file a sandboxed program could have replaced, opened by
    `visphy_core.infra.files.open_untrusted` (no symbolic link, non-blocking, a regular file
    only, at most ``max_bytes``; ``allowed`` says what that cap is, for the message); else
    `FrameRejected` naming why. The caller closes the fd."""
    name = Path(path).name
    try:
        return files.open_untrusted(path, max_bytes)
    except FileNotFoundError:
        raise FrameRejected(f"{name} is missing") from None
    except files.ForeignFileError as exc:
        raise FrameRejected(_refusal(name, exc, max_bytes, allowed)) from None
    except OSError as exc:
        raise FrameRejected(f"{name} cannot be opened: {exc.strerror}") from None


def _refusal(name: str, exc: files.ForeignFileError, max_bytes: int,
             allowed: str | None) -> str:
    if exc.why == "link":
        return f"{name} is a symbolic link, not a file the renderer wrote: refused"
    if exc.why == "too_large":
        return (f"{name} is {exc.size} bytes, more than "
                f"{allowed or f'the {max_bytes} allowed'}: refused unread")
    return f"{name} is not a regular file: refused"


def read_untrusted_png(path: str | os.PathLike, width: int, height: int) -> np.ndarray:
    """One untrusted PNG frame as RGB uint8 ``height×width×3``: `open_untrusted` (no links,
    regular file, at most `png_size_cap` bytes), then the 33-byte header is read and checked
    (a PNG, exactly ``width×height``) before the rest of the file is read and decoded. Any
    refusal is `FrameRejected` with the file's name and the reason."""
    name = Path(path).name
    cap = png_size_cap(width, height)
    fd, size = open_untrusted(path, cap, f"a {width}x{height} PNG can need ({cap} bytes)")
    try:
        head = files.read_upto(fd, PNG_HEADER_BYTES)
        header = parse_png_header(head, name)
        _refuse_size(name, header, width, height)
        # at most the size fstat saw (and the cap): a file that grows meanwhile is cut off
        data = head + files.read_upto(fd, min(size, cap) - len(head))
    finally:
        os.close(fd)
    return decode_untrusted_png(data, width, height, name)
