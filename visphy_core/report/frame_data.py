"""Per-frame data of one scene for the report's plots, computed from the two clips the report
already shows and cached beside its media (``media/.plots.json``, keyed like
``media/.sources.json`` by each input's path, size and modification time).

* **PSNR per frame** (dB) of the generated clip against the ground truth, frames paired by index
  (the plain ``visphy`` pairing), and of the *still clip* (the ground truth's first frame held:
  what the fallback clip and the ``static`` baseline show) against it, for scale. Each value is
  the ``psnr`` metric's own (`visphy_core.api.psnr.psnr`): a perfect match is its 100 dB cap.
* **Body centroids per frame** in both clips: each tracked body (``metric_details.json``'s
  ``tracks.tracked``, else the spec's dynamic bodies of a colour no other body shares) is the
  set of pixels nearest to its spec colour among every colour of the scene (2D: RGB distance
  within `FLAT_MAX_DIST`; 3D: chromaticity, the angle between RGB vectors, within
  `SHADED_MAX_DEG`; colours quantised to 5 bits a channel), on a grid of every
  ``min(h, w) // 256``-th pixel. This is a quick colour look-up for a picture, not the track
  metrics' tracker (which also follows paler or recoloured bodies): a body drawn in another
  colour is "not found" here, and the report says so.

Both clips are decoded once, frame by frame side by side (memory: a few frames), up to
`MAX_FRAMES` frames; the result is a small JSON dictionary, or a reason why there is none.
"""

from __future__ import annotations

import json
import math
from itertools import zip_longest
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from visphy_core.api.psnr import psnr
from visphy_core.report.media import av_errors, file_stamp, read_index, write_index

#: Bumped when what is computed changes: older cache entries are recomputed.
VERSION = 2
CACHE = ".plots.json"
#: Frames compared at most (longer clips: the first ones, and the report says so).
MAX_FRAMES = 600
#: How near a pixel must be to a body's colour (see the module docstring).
FLAT_MAX_DIST = 90.0
SHADED_MAX_DEG = 10.0
SHADED_MIN_BRIGHTNESS = 24
#: Grid samples a body needs in a frame to be "found".
MIN_SAMPLES = 4


def _stamp(path: Path | None) -> str:
    return file_stamp(path) if path is not None and path.is_file() else "-"


def _rgb(value: Any) -> tuple[int, int, int] | None:
    try:
        r, g, b = (int(round(float(v))) for v in list(value)[:3])
    except (TypeError, ValueError):
        return None
    return (min(max(r, 0), 255), min(max(g, 0), 255), min(max(b, 0), 255))


def _json(path: Path | None) -> Any:
    if path is None or not path.is_file():
        return None
    try:
        return json.loads(path.read_text("utf-8", errors="replace"))
    except ValueError:
        return None


def palette(spec: Any, details: Any) -> tuple[str, list[str], list[tuple], list[tuple]] | str:
    """``(dim, tracked ids, their colours, every colour of the scene)`` from the ground-truth
    spec and the scene's metric details, or why there is none."""
    if not isinstance(spec, dict) or not isinstance(spec.get("bodies"), list):
        return "no ground-truth spec with bodies (body colours unknown)"
    dim = str(spec.get("dim") or "2d")
    bodies = [(str(b.get("id")), _rgb(b.get("color_rgb")), bool(b.get("dynamic")))
              for b in spec["bodies"] if isinstance(b, dict)]
    bodies = [b for b in bodies if b[1] is not None]
    colours = {bid: rgb for bid, rgb, _ in bodies}
    tracks = (details or {}).get("tracks") if isinstance(details, dict) else None
    if isinstance(tracks, dict) and isinstance(tracks.get("tracked"), list):
        ids = [str(i) for i in tracks["tracked"] if str(i) in colours]
    else:
        ids = [bid for bid, rgb, dyn in bodies
               if dyn and [c for _, c, _ in bodies].count(rgb) == 1]
    if not ids:
        return "no tracked body (no dynamic body of a colour of its own)"
    others = [_rgb((spec.get("render") or {}).get("background_rgb")) or (255, 255, 255)]
    floor = _rgb(((spec.get("world") or {}).get("floor") or {}).get("color_rgb"))
    if floor is not None:
        others.append(floor)
    scene = [colours[i] for i in ids] + [c for _, c, _ in bodies if c not in
                                         [colours[i] for i in ids]] + others
    return dim, ids, [colours[i] for i in ids], list(dict.fromkeys(scene))


class Locator:
    """Each tracked body's centroid in a frame, by nearest scene colour (module docstring),
    through a look-up table over the RGB cube quantised to `BITS` bits a channel."""

    BITS = 5

    def __init__(self, dim: str, tracked: list[tuple], scene: list[tuple]):
        self.n = len(tracked)
        q = np.arange(1 << self.BITS, dtype=np.float32) * (1 << (8 - self.BITS)) \
            + ((1 << (8 - self.BITS)) - 1) / 2.0
        cube = np.stack(np.meshgrid(q, q, q, indexing="ij"), -1).reshape(-1, 3)
        cols = np.array(scene, dtype=np.float32)
        if dim == "3d":
            cols = np.concatenate([cols, np.full((1, 3), 255.0, np.float32)])  # neutral axis
            dark = cols.max(1) < SHADED_MIN_BRIGHTNESS
            unit = cols / np.maximum(np.linalg.norm(cols, axis=1, keepdims=True), 1e-6)
            cos = (cube / np.maximum(np.linalg.norm(cube, axis=1, keepdims=True), 1e-6)) @ unit.T
            cos[:, dark] = -2.0
            best = cos.argmax(1)
            ok = ((cos[np.arange(len(cube)), best] >= math.cos(math.radians(SHADED_MAX_DEG)))
                  & (cube.max(1) >= SHADED_MIN_BRIGHTNESS))
        else:
            d2 = ((cube[:, None, :] - cols[None, :, :]) ** 2).sum(-1)
            best = d2.argmin(1)
            ok = d2[np.arange(len(cube)), best] <= FLAT_MAX_DIST ** 2
        self.lut = np.where(ok & (best < self.n), best + 1, 0).astype(np.uint8)

    def __call__(self, frame: np.ndarray) -> list[list[float] | None]:
        stride = max(1, min(frame.shape[0], frame.shape[1]) // 256)
        px = frame[::stride, ::stride] >> (8 - self.BITS)
        key = ((px[..., 0].astype(np.int32) << (2 * self.BITS))
               | (px[..., 1].astype(np.int32) << self.BITS) | px[..., 2])
        labels = self.lut[key]
        flat = labels.ravel()
        counts = np.bincount(flat, minlength=self.n + 1)
        found = np.flatnonzero(flat)
        sx = np.bincount(flat[found], weights=found % labels.shape[1], minlength=self.n + 1)
        sy = np.bincount(flat[found], weights=found // labels.shape[1], minlength=self.n + 1)
        out: list[list[float] | None] = []
        for k in range(1, self.n + 1):
            if counts[k] < MIN_SAMPLES:
                out.append(None)
                continue
            out.append([round(float(sx[k] / counts[k] * stride + 0.5), 1),
                        round(float(sy[k] / counts[k] * stride + 0.5), 1)])
        return out


def _frames(path: Path) -> Iterator[np.ndarray]:
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        for i, frame in enumerate(container.decode(stream)):
            if i >= MAX_FRAMES:
                return
            yield frame.to_ndarray(format="rgb24")


def compute(truth: Path, generated: Path, spec: Any, details: Any) -> dict:
    """The per-frame data of one scene (see the module docstring); ``tracks`` holds a reason
    string instead of centroids when the bodies cannot be located."""
    pal = palette(spec, details)
    locate = Locator(pal[0], pal[2], pal[3]) if not isinstance(pal, str) else None
    psnr_gen: list[float] = []
    still: list[float] = []
    ref_c: list[list] = []
    gen_c: list[list] = []
    first = None
    n_truth = n_gen = 0
    size = gen_size = None
    try:
        for t, g in zip_longest(_frames(truth), _frames(generated)):
            n_truth += t is not None
            n_gen += g is not None
            if t is not None:
                size = size or [t.shape[1], t.shape[0]]
                first = t if first is None else first
                if locate is not None:
                    ref_c.append(locate(t))
            if g is not None:
                gen_size = gen_size or [g.shape[1], g.shape[0]]
                if locate is not None:
                    gen_c.append(locate(g))
            if t is not None and g is not None and t.shape == g.shape:
                psnr_gen.append(psnr(g, t))
                still.append(psnr(first, t))
    except (OSError, ValueError, av_errors()) as exc:
        return {"error": f"cannot decode the clips: {type(exc).__name__}: {exc}"}
    out: dict[str, Any] = {"size": size, "n_truth": n_truth, "n_generated": n_gen,
                           "cut": max(n_truth, n_gen) >= MAX_FRAMES}
    if size != gen_size:
        out["psnr_error"] = (f"frame sizes differ (ground truth {size}, generated "
                             f"{gen_size}): no per-frame PSNR")
    else:
        out |= {"psnr": psnr_gen, "still": still}
    if isinstance(pal, str):
        out["tracks"] = pal
    else:
        scale = ([size[0] / gen_size[0], size[1] / gen_size[1]]
                 if size and gen_size and size != gen_size else [1.0, 1.0])
        out["tracks"] = {"ids": pal[1], "colours": [list(c) for c in pal[2]],
                         "truth": [[c[k] for c in ref_c] for k in range(len(pal[1]))],
                         "generated": [[None if c[k] is None else
                                        [round(c[k][0] * scale[0], 1),
                                         round(c[k][1] * scale[1], 1)]
                                        for c in gen_c] for k in range(len(pal[1]))]}
    return out


class FrameData:
    """Per-scene frame data, computed once per pair of clips and cached in the report's
    ``media/.plots.json``."""

    def __init__(self, report_dir: Path):
        self.path = Path(report_dir) / "media" / CACHE
        self.entries: dict[str, dict] = read_index(self.path)
        self.used: dict[str, dict] = {}

    def get(self, key: str, truth: Path, generated: Path, spec_path: Path | None,
            details_path: Path) -> dict:
        stamp = "|".join([str(VERSION)] + [_stamp(p) for p in (truth, generated, spec_path,
                                                                 details_path)])
        entry = self.entries.get(key)
        if not entry or entry.get("stamp") != stamp:
            entry = {"stamp": stamp, "data": compute(truth, generated, _json(spec_path),
                                                     _json(details_path))}
        self.used[key] = entry
        return entry["data"]

    def close(self) -> None:
        """Save the entries this report used (others are dropped)."""
        if self.used or self.path.is_file():
            write_index(self.path, json.dumps(self.used, sort_keys=True, separators=(",", ":")))
