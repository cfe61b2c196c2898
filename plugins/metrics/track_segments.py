"""The object-track metrics' segmentation (`tracks.py`): each clip's bodies found by their palette
colour on a sampling grid, the reference's by its exact palette and the generated clip's with
colour-tolerant association, and the centroid tracks both give."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from visphy_core.api.metrics import MetricInput
from visphy_plugins.metrics.association import Row, associate, dominant_colours, find_blobs
from visphy_plugins.metrics.track_palette import (
    Palette,
    _fill,
    _rgb,
    _same_colour,
    scene_palette,
)

PRESENT_FRACTION = 0.03         # of the body's largest area in the reference
MIN_SAMPLES = 4                 # grid samples a present body needs at least
AGREE_RADIUS_FRACTION, AGREE_PX = 0.1, 2.0  # palette and association agree: centroids...
AGREE_AREA_RATIO = 0.8                      # ...and the palette sees most of the blob...
AGREE_FRAMES = 0.5                          # ...in this fraction of the frames


@dataclass
class Tracks:
    """One clip's observations of each tracked body in each frame (see the module docstring):
    ``area``, the px of the body (core and the outline touching it, N×B); ``core``, the px of
    its core (N×B); ``centroid``, the body's (x, y) px centroid (N×B×2, NaN where not seen);
    ``stride``, the sampling grid's step."""

    ids: tuple[str, ...]
    area: np.ndarray
    centroid: np.ndarray
    stride: int = 1
    core: np.ndarray | None = None

_CHUNK = 8  # frames segmented at a time


def grid_stride(height: int, width: int) -> int:
    return max(1, min(height, width) // 256)


def palette_labels(palette: Palette, g: np.ndarray) -> np.ndarray:
    """The palette label (0: none, k + 1: tracked body k) of every pixel of an …×3 uint8
    array."""
    bits, sh = palette.bits, 8 - palette.bits
    key = (g[..., 0] >> sh).astype(np.uint32)
    key <<= bits
    key |= g[..., 1] >> sh
    key <<= bits
    key |= g[..., 2] >> sh
    return _fill(palette, key)[key]


def segment(frames: np.ndarray, palette: Palette, stride: int | None = None) -> Tracks:
    """Segment every tracked body of ``palette`` in every frame of an N×H×W×3 uint8 clip."""
    frames = np.asarray(frames)
    n, h, w = frames.shape[:3]
    n_b = len(palette.tracked)
    area = np.zeros((n, n_b))
    centroid = np.full((n, n_b, 2), np.nan)
    s = grid_stride(h, w) if stride is None else int(stride)
    if n == 0 or n_b == 0:
        return Tracks(palette.ids, area, centroid, s, area.copy())
    gh, gw = len(range(0, h, s)), len(range(0, w, s))
    count = np.zeros(n * n_b)
    core = np.zeros(n * n_b)
    sx = np.zeros(n * n_b)
    sy = np.zeros(n * n_b)
    lab = np.zeros((_CHUNK, gh + 2, gw + 2), np.uint8)
    core_map = np.zeros_like(lab)
    for i in range(0, n, _CHUNK):  # a few frames at a time: the work stays in the CPU caches
        g = frames[i:i + _CHUNK, ::s, ::s]
        m = len(g)
        lab[:m, 1:-1, 1:-1] = palette_labels(palette, g)
        # edges replicated: a body cut by the frame border keeps its border samples
        lab[:m, 0], lab[:m, -1] = lab[:m, 1], lab[:m, -2]
        lab[:m, :, 0], lab[:m, :, -1] = lab[:m, :, 1], lab[:m, :, -2]
        fr, y, x = np.nonzero(lab[:m, 1:-1, 1:-1])
        y += 1
        x += 1
        lv = lab[fr, y, x]
        keep = ((lab[fr, y - 1, x] == lv) & (lab[fr, y + 1, x] == lv)
                & (lab[fr, y, x - 1] == lv) & (lab[fr, y, x + 1] == lv))
        core_map[:m] = 0
        core_map[fr[keep], y[keep], x[keep]] = lv[keep]
        near = (keep | (core_map[fr, y - 1, x] == lv) | (core_map[fr, y + 1, x] == lv)
                | (core_map[fr, y, x - 1] == lv) | (core_map[fr, y, x + 1] == lv))
        group = (fr + i) * n_b + lv.astype(np.int64) - 1
        core += np.bincount(group[keep], minlength=n * n_b)
        group, x, y = group[near], x[near], y[near]
        count += np.bincount(group, minlength=n * n_b)
        sx += np.bincount(group, weights=x, minlength=n * n_b)
        sy += np.bincount(group, weights=y, minlength=n * n_b)
    count, core = count.reshape(n, n_b), core.reshape(n, n_b)
    sx, sy = sx.reshape(n, n_b), sy.reshape(n, n_b)
    with np.errstate(invalid="ignore", divide="ignore"):
        centroid[..., 0] = np.where(count > 0, (sx / count - 1) * s + 0.5, np.nan)
        centroid[..., 1] = np.where(count > 0, (sy / count - 1) * s + 0.5, np.nan)
    return Tracks(palette.ids, count * (s * s), centroid, s, core * float(s * s))


def scene_tracks(inp: MetricInput) -> dict | None:
    """The segmentation of both clips (memoised in ``inp.extra["tracks"]``): palette, reference
    and generated `Tracks`, presence masks, the skipped bodies, and how each generated
    observation was found (``gen_source``: 0 not found, 1 palette, 2 association;
    ``gen_colour_cost``: the associated blob's colour cost). None without a palette."""
    key = (id(inp.reference), id(inp.generated))
    memo = inp.extra.get("tracks")
    if memo is not None and memo.get("key") == key:
        return memo["value"]
    palette = scene_palette(inp.scene)
    if palette is None:
        value = None
    else:
        ref = segment(inp.reference, palette)
        floor = MIN_SAMPLES * ref.stride ** 2
        max_area = ref.area.max(axis=0, initial=0.0)
        min_area = np.maximum(floor, PRESENT_FRACTION * max_area)
        ref_present = (ref.area >= min_area) & (ref.core >= floor)
        gen, source, cost = generated_tracks(inp.generated, palette, ref, ref_present,
                                             min_area, floor, inp.scene,
                                             keep=inp.extra.setdefault("tracks.blobs", {}))
        value = {"palette": palette, "ref": ref, "gen": gen,
                 "ref_present": ref_present,
                 "gen_present": (gen.area >= min_area) & (gen.core >= floor),
                 "gen_source": source, "gen_colour_cost": cost,
                 "max_area": max_area,
                 "skipped": dict(palette.skipped), "tracked": list(palette.ids)}
    inp.extra["tracks"] = {"key": key, "value": value}
    return value


def other_rows(scene, palette: Palette) -> list[Row]:
    """The scene's bodies that are not tracked (static ones, ones that share a colour), each
    to claim the blob it explains, from the detection (``objects[]``: colour, ``position``,
    ``size``: circles π·r², bars length × thickness, other shapes half their bbox). None
    without a detection."""
    try:
        det = scene.detection
    except Exception:  # noqa: BLE001 - an unreadable detection: no such rows
        det = None
    if not isinstance(det, dict) or not isinstance(det.get("objects"), list):
        return []
    out = []
    for o in det["objects"]:
        if not isinstance(o, dict) or str(o.get("id")) in palette.ids:
            continue
        rgb = _rgb(o.get("color_rgb"))
        if rgb is None or any(_same_colour(palette.mode, rgb, c) for c in palette.background):
            continue
        try:
            pos = o.get("position") or {}
            at = (float(pos["center_x"]), float(pos["center_y"]))
        except (KeyError, TypeError, ValueError):
            at = (math.nan, math.nan)
        size, box = o.get("size") or {}, o.get("bbox") or {}
        try:
            if "radius_pixels" in size:
                area = math.pi * float(size["radius_pixels"]) ** 2
            elif "length_pixels" in size:
                area = float(size["length_pixels"]) * float(size["thickness_pixels"])
            else:
                area = 0.5 * float(box["width"]) * float(box["height"])
        except (KeyError, TypeError, ValueError):
            area = math.nan
        if math.isfinite(area) and area > 0:
            out.append(Row(rgb, area, at))
    return out


def generated_tracks(frames: np.ndarray, palette: Palette, ref: Tracks, ref_present: np.ndarray,
                     min_area: np.ndarray, floor: float, scene=None, keep: dict | None = None):
    """The generated clip's observations: the palette segmentation where it finds a body and
    agrees with the colour-tolerant association (`plugins/metrics/association.py`), the
    associated blobs elsewhere (module docstring). Returns (`Tracks`, source N×B, colour cost
    N×B). ``keep``: a dict that receives the clip's blobs (``key``: ``id(frames)``, ``blobs``;
    `plugins/metrics/object_level.py` reuses them)."""
    frames = np.asarray(frames)
    pal = segment(frames, palette)
    n, n_b = pal.area.shape
    source = np.where((pal.area >= min_area) & (pal.core >= floor), 1, 0)
    cost = np.full((n, n_b), np.nan)
    if n == 0 or n_b == 0:
        return pal, source, cost
    h, w = frames.shape[1:3]
    s = pal.stride
    background = palette.background + tuple(dominant_colours(frames, s))
    blobs = find_blobs(frames, background, s, MIN_SAMPLES,
                       lambda g: palette_labels(palette, g), n_b)
    if keep is not None:
        keep.update(key=id(frames), blobs=blobs)
    max_area = ref.area.max(axis=0, initial=0.0)
    fallback = float(np.median(max_area[max_area > 0])) if (max_area > 0).any() else 100.0
    rows = []
    for b in range(n_b):
        seen = np.flatnonzero(ref_present[:, b])
        rows.append(Row(palette.tracked[b], float(max_area[b]) if max_area[b] > 0 else fallback,
                        tuple(ref.centroid[seen[0], b]) if len(seen) else (math.nan, math.nan)))
    others = other_rows(scene, palette)
    # colours of bodies that are not rows of their own (no detection) still keep a blob they
    # explain better from the tracked bodies
    loose = [c for c in palette.distractors
             if not any(_same_colour(palette.mode, c, r.rgb) for r in others)]
    assoc = associate(blobs, n, rows + others, loose, n_b, math.hypot(h, w))
    found = (assoc.area >= min_area) & (assoc.core >= floor)
    gap = np.hypot(*np.moveaxis(np.nan_to_num(pal.centroid - assoc.centroid, nan=np.inf), -1, 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = pal.area / assoc.area
    agree = ((gap <= AGREE_RADIUS_FRACTION * np.sqrt(assoc.area / math.pi) + AGREE_PX * s)
             & (ratio >= AGREE_AREA_RATIO))
    # per body, one source where both find it: the palette when it agrees with the
    # association in at least half of those frames (no jitter from switching between them)
    both = (source == 1) & found
    prefer_pal = (agree & both).sum(axis=0) >= AGREE_FRAMES * both.sum(axis=0)
    use = found & ~((source == 1) & prefer_pal[None, :])
    # the palette's region for a body lies mostly in blobs the association gave to other
    # bodies (a paler palette drawing another body near this one's colour): not this body
    for k, b in np.argwhere(source == 1):
        in_frame = np.flatnonzero(blobs.frame == k)
        owner, px = assoc.owner[in_frame], blobs.labels[in_frame, b + 1]
        if px[(owner >= 0) & (owner != b)].sum() > max(px[owner == b].sum(),
                                                      0.5 * pal.area[k, b]):
            source[k, b] = 0
            use[k, b] = found[k, b]
    source = np.where(use, 2, source)
    cost = np.where(found, assoc.cost, np.nan)
    area = np.where(use, assoc.area, np.where(source == 1, pal.area, 0.0))
    core = np.where(use, assoc.core, np.where(source == 1, pal.core, 0.0))
    centroid = np.where(use[..., None], assoc.centroid,
                        np.where((source == 1)[..., None], pal.centroid, np.nan))
    return Tracks(palette.ids, area, centroid, s, core), source, cost

