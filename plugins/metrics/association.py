"""Colour-tolerant association for the object-track metrics (`plugins/metrics/tracks.py`): the
generated clip is cut into blobs without its palette, and the scene's bodies are assigned,
frame by frame, to the blobs that best explain them by colour, size and motion.

Why: models draw the palette paler, tinted, shaded, anti-aliased or outlined (the red ball as
(247, 151, 142) instead of (243, 79, 70)); a fixed colour tolerance then loses a body whose path
is plausible. Colour is a cue here, not a gate.

Blobs (`find_blobs`)
    Per frame, on the tracker's sample grid: *foreground* is every sample farther than `FG_DE`
    (CIELAB ΔE) from each background colour: the scene's (2D background, 3D sky and floor) and
    the colours that cover at least `DOMINANT_FRACTION` of the clip's first, middle and last
    frames (a model's own background or floor). Neighbouring foreground samples join when their
    colours differ by less than the first of `EDGE_LEVELS` (ΔE and the angle between their RGB
    vectors): a blob is a region of smoothly varying colour (a shaded sphere stays one blob; a
    body and its dark outline, two touching bodies of different colours do not join). A blurred
    edge (anti-aliasing, H.264) can still chain two bodies of near colours, paler palettes most
    of all; a blob whose interior samples (joined to all four neighbours, L* ≥
    `SPLIT_MIN_LIGHTNESS`) hold a second chromaticity group (at least `SPLIT_MIN_SAMPLES` and
    `SPLIT_FRACTION` of them over `SPLIT_ANGLE_DEG` from the blob's mean) is cut again at the
    next, stricter level. As in the palette segmentation, a sample is *core* when its four
    neighbours are in its blob, and the blob is its core plus the samples touching it (thin
    outlines, anti-aliased fringes and noise have no core). Blobs with fewer than ``min_core``
    core samples, or larger than `MAX_BLOB_FRACTION` of the frame (a background), are not
    candidates. A blob's colour is the mean of its core samples.

Colour cost (`colour_cost`)
    A colour's chromatic part is its component orthogonal to the grey axis of RGB; its *hue* is
    that component's direction, its *chroma* C its length and its *saturation* s = C / ‖rgb‖.
    Mixing with white (a paler palette) and scaling (shading, dimmer lights) leave the hue
    unchanged, scaling leaves the saturation unchanged too (CIELAB's hue drifts under both), so
    the cost is

        d² = (w·Δhue / `HUE_SIGMA_DEG`)² + (Δln(s + `SAT_FLOOR`) / `SAT_SIGMA`)²
             + (ΔL* / `LIGHTNESS_SIGMA`)²,   w = C_min / (C_min + `CHROMA_HALF`)

    (C_min: the smaller chroma of the two; near-neutral colours have no reliable hue). On the
    benchmark's palette a 50% paler colour costs 0.5–1.3, a hue turned 15° 0.3–0.65, a 60%
    paler colour turned 20° at most 1.73; red against magenta 1.95, against PHYRE's grey 4.0.

Association (`associate`)
    Rows are the scene's bodies: the tracked ones, and the others the detection lists (static
    bodies, bodies sharing a colour), each of which claims the blob it explains so that no
    tracked body takes it; columns are the frame's candidate blobs. A blob is *eligible* for a
    row when their colour cost is at most `COLOUR_GATE` and no *loose* colour (a non-tracked
    body's colour with no row of its own: scenes without a detection) explains it better by
    more than `DISTRACTOR_MARGIN`. The cost of an eligible pair is colour² + size² +
    position²: size is |ln(area / expected)| / ln 2 (expected: the reference's largest area of a
    tracked body; π·r², length × thickness or half the bbox of a detected one), capped at
    `SIZE_CAP`; position is the distance to the row's predicted position (its last two
    positions in this clip extended at constant velocity, its last one held, or its first
    position — the reference's, or the detection's — before it was seen) over max(its
    equivalent radius, half its last step, `POS_SIGMA_MIN`), capped at `POS_CAP`, so a body that
    moves wrongly is still found by its colour. One min-cost assignment per frame
    (`scipy.optimize.linear_sum_assignment`) with a private "missing" column per row at
    `MISSING_COST` (above any eligible pair's cost): a body is missing when it has no eligible
    blob, or only blobs that another body explains at a lower total cost. The blobs touching
    a tracked body's blob (within `TOUCH_SAMPLES` grid steps, transitively) whose colour is
    within `MERGE_COST` of it with lightness ignored (the faces of a shaded box, pieces of a
    body cut by an occluder), that no row took and whose best tracked row is this body, join it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

FG_DE = 6.0               # ΔE from every background colour: foreground
#: neighbouring samples of one blob differ by less than ΔE and chromaticity angle (degrees
#: between their RGB vectors): the first level, then stricter ones for mixed blobs
EDGE_LEVELS = ((12.0, 6.0), (6.0, 3.0), (3.0, 1.5))
SPLIT_ANGLE_DEG = 4.0     # a blob with two chromaticity groups: at least this many
SPLIT_MIN_SAMPLES, SPLIT_FRACTION = 8, 0.02  # ...and this fraction of its samples off
SPLIT_MIN_LIGHTNESS = 20.0  # L*: darker samples have no reliable chromaticity
DOMINANT_FRACTION = 0.12  # a colour covering this much of a frame is a background
MAX_BLOB_FRACTION = 0.2   # a blob larger than this much of the frame is a background
HUE_SIGMA_DEG = 30.0      # colour cost: degrees of hue...
SAT_FLOOR, SAT_SIGMA = 0.02, math.log(3.0)  # ...saturation ratio...
LIGHTNESS_SIGMA = 40.0    # ...and L* that cost 1
CHROMA_HALF = 10.0        # RGB units: the chroma at which hue counts half
COLOUR_GATE = 1.75        # colour cost beyond which a body never takes a blob
DISTRACTOR_MARGIN = 0.25  # a loose colour explaining a blob better by more: not eligible
MISSING_COST = 8.0        # a body left without a blob (more than any eligible pair's cost)
SIZE_CAP, POS_CAP = 1.5, 1.5
POS_SIGMA_MIN = 8.0       # px
MERGE_COST = 0.5          # colour cost (lightness ignored) of blobs that join one body
TOUCH_SAMPLES = 2         # grid steps: blobs this close touch
_BITS = 6                 # quantisation of the colour tables (6 bits a channel)
_CHUNK = 8

_U = np.array([2.0, -1.0, -1.0]) / math.sqrt(6.0)
_V = np.array([0.0, 1.0, -1.0]) / math.sqrt(2.0)


# ------------------------------------------------------------------------------ colour
def srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of M×3 sRGB values in 0..255."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    m = np.array([[0.4124564, 0.3575761, 0.1804375],
                  [0.2126729, 0.7151522, 0.0721750],
                  [0.0193339, 0.1191920, 0.9503041]])
    xyz = lin @ m.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]),
                     200 * (f[..., 1] - f[..., 2])], axis=-1)


@dataclass(frozen=True)
class ColourFeatures:
    """Per colour: hue (rad), chroma (RGB units), saturation and L* (see the module docstring)."""

    hue: np.ndarray
    chroma: np.ndarray
    sat: np.ndarray
    light: np.ndarray

    def __getitem__(self, i) -> "ColourFeatures":
        return ColourFeatures(self.hue[i], self.chroma[i], self.sat[i], self.light[i])


def colour_features(rgb) -> ColourFeatures:
    x = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
    a, b = x @ _U, x @ _V
    chroma = np.hypot(a, b)
    return ColourFeatures(np.arctan2(b, a), chroma,
                          chroma / np.maximum(np.linalg.norm(x, axis=1), 1.0),
                          srgb_to_lab(x)[:, 0])


def colour_cost(p: ColourFeatures, q: ColourFeatures,
                light_sigma: float = LIGHTNESS_SIGMA) -> np.ndarray:
    """The tint-tolerant colour distance (len(p)×len(q), in gate units) of every pair
    (``light_sigma=inf``: lightness ignored, as between two faces of one shaded body)."""
    dh = np.abs(np.angle(np.exp(1j * (p.hue[:, None] - q.hue[None, :]))))
    cmin = np.minimum(p.chroma[:, None], q.chroma[None, :])
    w = cmin / (cmin + CHROMA_HALF)
    ds = np.log((q.sat[None, :] + SAT_FLOOR) / (p.sat[:, None] + SAT_FLOOR))
    dl = q.light[None, :] - p.light[:, None]
    return np.sqrt((w * np.degrees(dh) / HUE_SIGMA_DEG) ** 2 + (ds / SAT_SIGMA) ** 2
                   + (dl / light_sigma) ** 2)


@lru_cache(maxsize=1)
def _lab_table() -> np.ndarray:
    """CIELAB at the centre of every cell of the quantised RGB cube (float32)."""
    n = 1 << _BITS
    q = np.arange(n, dtype=np.float64) * (256 / n) + (256 / n - 1) / 2
    r, g, b = np.meshgrid(q, q, q, indexing="ij")
    return srgb_to_lab(np.stack([r, g, b], axis=-1).reshape(-1, 3)).astype(np.float32)


@lru_cache(maxsize=1)
def _chroma_table() -> np.ndarray:
    """The unit RGB vector (chromaticity) at the centre of every cell (float32)."""
    n = 1 << _BITS
    q = np.arange(n, dtype=np.float64) * (256 / n) + (256 / n - 1) / 2
    r, g, b = np.meshgrid(q, q, q, indexing="ij")
    rgb = np.stack([r, g, b], axis=-1).reshape(-1, 3)
    return (rgb / np.linalg.norm(rgb, axis=1, keepdims=True)).astype(np.float32)


@lru_cache(maxsize=16)
def _foreground_table(background: tuple[tuple[float, float, float], ...]) -> np.ndarray:
    lab = _lab_table()
    fg = np.ones(len(lab), bool)
    for colour in background:
        ref = srgb_to_lab(np.array([colour], float))[0].astype(np.float32)
        fg &= ((lab - ref) ** 2).sum(1) > FG_DE ** 2
    return fg


def _keys(g: np.ndarray) -> np.ndarray:
    sh = 8 - _BITS
    key = (g[..., 0] >> sh).astype(np.uint32)
    key <<= _BITS
    key |= g[..., 1] >> sh
    key <<= _BITS
    key |= g[..., 2] >> sh
    return key


def dominant_colours(frames: np.ndarray, stride: int) -> list[tuple[float, float, float]]:
    """Mean colours of the coarse colour cells (4 bits a channel) that each cover at least
    `DOMINANT_FRACTION` of the first, middle or last frame: a clip's backgrounds."""
    out = []
    n = len(frames)
    for k in sorted({0, n // 2, n - 1}) if n else ():
        g = frames[k, ::stride, ::stride].reshape(-1, 3)
        key = ((g[:, 0] >> 4).astype(np.int64) << 8) | ((g[:, 1] >> 4).astype(np.int64) << 4) \
            | (g[:, 2] >> 4)
        count = np.bincount(key, minlength=4096)
        for cell in np.flatnonzero(count >= DOMINANT_FRACTION * len(g)):
            sel = g[key == cell].astype(np.float64)
            out.append(tuple(float(v) for v in np.round(sel.mean(0))))
    return out


# ------------------------------------------------------------------------------ blobs
def _components(n: int, src: np.ndarray, dst: np.ndarray, lab: np.ndarray, unit: np.ndarray):
    """Connected components of ``n`` samples joined by the neighbour pairs (src, dst) whose
    colours are close (`EDGE_LEVELS`: ΔE and chromaticity angle); a component whose samples'
    chromaticities form more than one group (at least `SPLIT_MIN_SAMPLES` and more than
    `SPLIT_FRACTION` of its bright interior samples, those joined to all four neighbours, over
    `SPLIT_ANGLE_DEG` from their mean: two bodies joined through a blurred edge) is cut again
    at the next, stricter level."""
    de2 = ((lab[src] - lab[dst]) ** 2).sum(-1)
    cos = (unit[src] * unit[dst]).sum(-1)
    bright = lab[:, 0] >= SPLIT_MIN_LIGHTNESS
    active = np.ones(len(src), bool)  # pairs subject to the current level
    joined = np.zeros(len(src), bool)
    comp = np.zeros(n, np.int64)
    n_comp = 0
    for level, (de, angle) in enumerate(EDGE_LEVELS):
        joined = np.where(active, (de2 < de * de) & (cos > math.cos(math.radians(angle))),
                          joined)
        graph = coo_matrix((np.ones(int(joined.sum()), np.int8),
                            (src[joined], dst[joined])), shape=(n, n))
        n_comp, comp = connected_components(graph, directed=False)
        if level == len(EDGE_LEVELS) - 1:
            break
        degree = (np.bincount(src[joined], minlength=n)
                  + np.bincount(dst[joined], minlength=n))
        inner = bright & (degree == 4)  # interior samples: no blurred edges, no fringes
        # float even when no sample is interior (numpy's bincount of nothing is int64)
        mean = np.stack([np.bincount(comp[inner], weights=unit[inner, j], minlength=n_comp)
                         for j in range(3)], axis=1).astype(np.float64)
        mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-9)
        off = inner & ((unit * mean[comp]).sum(1) < math.cos(math.radians(SPLIT_ANGLE_DEG)))
        n_off = np.bincount(comp[off], minlength=n_comp)
        mixed = (n_off >= SPLIT_MIN_SAMPLES) & (
            n_off > SPLIT_FRACTION * np.bincount(comp[inner], minlength=n_comp))
        if not mixed.any():
            break
        active = mixed[comp[src]]
    return n_comp, comp


@dataclass
class Blobs:
    """Candidate blobs of a clip: ``frame`` (index), ``area`` and ``core`` (px), ``centroid``
    ((x, y) px, continuous image coordinates), ``rgb`` (mean colour of the core) and
    ``touching`` (K×2 blob indices: pairs whose samples come within `TOUCH_SAMPLES` grid steps
    of each other) and ``labels`` (px of each label of a ``labeller``, see `find_blobs`)."""

    frame: np.ndarray
    area: np.ndarray
    core: np.ndarray
    centroid: np.ndarray
    rgb: np.ndarray
    touching: np.ndarray
    labels: np.ndarray

    def __len__(self) -> int:
        return len(self.frame)


def find_blobs(frames: np.ndarray, background, stride: int, min_core: int,
               labeller=None, n_labels: int = 0) -> Blobs:
    """Every candidate blob of every frame of an N×H×W×3 uint8 clip (module docstring).
    ``labeller`` (K×3 uint8 colours → labels 0..n_labels): each blob also counts its samples of
    every label (``labels``: M×(n_labels + 1))."""
    frames = np.asarray(frames)
    n, h, w = frames.shape[:3]
    s = stride
    bg = tuple(dict.fromkeys(tuple(float(v) for v in c) for c in background))
    fg_lut, lab_lut, chroma_lut = _foreground_table(bg), _lab_table(), _chroma_table()
    gh, gw = len(range(0, h, s)), len(range(0, w, s))
    max_core = MAX_BLOB_FRACTION * gh * gw
    parts: list[tuple] = []
    n_blobs = 0
    for i in range(0, n, _CHUNK):
        g = frames[i:i + _CHUNK, ::s, ::s]
        m = len(g)
        key = _keys(g)
        fg = fg_lut[key]
        idx = np.full(fg.shape, -1, np.int32)
        n_fg = int(fg.sum())
        if n_fg == 0:
            continue
        idx[fg] = np.arange(n_fg, dtype=np.int32)
        lab = lab_lut[key[fg]]
        unit = chroma_lut[key[fg]]
        src, dst = [], []
        for a, b in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                     ((slice(None), slice(None), slice(None, -1)),
                      (slice(None), slice(None), slice(1, None)))):
            ia, ib = idx[a], idx[b]
            both = (ia >= 0) & (ib >= 0)
            src.append(ia[both])
            dst.append(ib[both])
        n_comp, comp = _components(n_fg, np.concatenate(src), np.concatenate(dst), lab, unit)
        lab_map = np.zeros((m, gh + 2, gw + 2), np.int32)
        inner = lab_map[:, 1:-1, 1:-1]
        inner[fg] = comp + 1
        lab_map[:, 0], lab_map[:, -1] = lab_map[:, 1], lab_map[:, -2]
        lab_map[:, :, 0], lab_map[:, :, -1] = lab_map[:, :, 1], lab_map[:, :, -2]
        fr, y, x = np.nonzero(fg)
        y += 1
        x += 1
        lv = lab_map[fr, y, x]
        keep = ((lab_map[fr, y - 1, x] == lv) & (lab_map[fr, y + 1, x] == lv)
                & (lab_map[fr, y, x - 1] == lv) & (lab_map[fr, y, x + 1] == lv))
        core_map = np.zeros_like(lab_map)
        core_map[fr[keep], y[keep], x[keep]] = lv[keep]
        near = (keep | (core_map[fr, y - 1, x] == lv) | (core_map[fr, y + 1, x] == lv)
                | (core_map[fr, y, x - 1] == lv) | (core_map[fr, y, x + 1] == lv))
        c = lv - 1
        core = np.bincount(c[keep], minlength=n_comp)
        good = (core >= min_core) & (core <= max_core)
        if not good.any():
            continue
        cnt = np.bincount(c[near], minlength=n_comp)
        sx = np.bincount(c[near], weights=x[near], minlength=n_comp)
        sy = np.bincount(c[near], weights=y[near], minlength=n_comp)
        if labeller is not None:
            lbl = labeller(g[fr[near], y[near] - 1, x[near] - 1]).astype(np.int64)
            counts = np.bincount(c[near] * (n_labels + 1) + lbl,
                                 minlength=n_comp * (n_labels + 1)).reshape(n_comp, -1)
        else:
            counts = np.zeros((n_comp, n_labels + 1))
        pix = g[fr[keep], y[keep] - 1, x[keep] - 1].astype(np.float64)
        rgb = np.stack([np.bincount(c[keep], weights=pix[:, j], minlength=n_comp)
                        for j in range(3)], axis=1)
        frame_of = np.zeros(n_comp, np.int64)
        frame_of[c] = fr + i
        sel = np.flatnonzero(good)
        blob_of = np.full(n_comp + 1, -1, np.int64)
        blob_of[sel + 1] = np.arange(len(sel)) + n_blobs
        parts.append((frame_of[sel], cnt[sel] * float(s * s), core[sel] * float(s * s),
                      np.stack([(sx[sel] / cnt[sel] - 1) * s + 0.5,
                                (sy[sel] / cnt[sel] - 1) * s + 0.5], axis=1),
                      rgb[sel] / core[sel][:, None],
                      _touching(blob_of[lab_map], fr, y, x),
                      counts[sel] * float(s * s)))
        n_blobs += len(sel)
    if not parts:
        return Blobs(np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros((0, 2)),
                     np.zeros((0, 3)), np.zeros((0, 2), np.int64), np.zeros((0, n_labels + 1)))
    return Blobs(*(np.concatenate(p) for p in zip(*parts)))


def _touching(blob_map: np.ndarray, fr: np.ndarray, y: np.ndarray, x: np.ndarray
              ) -> np.ndarray:
    """Pairs of distinct blobs (indices ≥ 0 in an m×H×W map) within `TOUCH_SAMPLES` grid steps
    of each other; (fr, y, x): the map's foreground samples."""
    t = TOUCH_SAMPLES
    padded = np.pad(blob_map, ((0, 0), (0, t), (t, t)), constant_values=-1)
    a = blob_map[fr, y, x]
    on = a >= 0
    fr, y, x, a = fr[on], y[on], x[on] + t, a[on]
    big = np.int64(blob_map.max()) + 1
    keys = []
    for dy in range(t + 1):
        for dx in range(-t, t + 1):
            if (dy, dx) <= (0, 0) or dy * dy + dx * dx > t * t:
                continue
            b = padded[fr, y + dy, x + dx]
            hit = (b >= 0) & (b != a)
            lo, hi = np.minimum(a[hit], b[hit]), np.maximum(a[hit], b[hit])
            keys.append(lo.astype(np.int64) * big + hi)
    key = np.unique(np.concatenate(keys))
    return np.stack([key // big, key % big], axis=1)


# ------------------------------------------------------------------------------ association
@dataclass(frozen=True)
class Row:
    """One ground-truth body to find: its colour, expected area (px) and first position
    ((x, y) px; NaN when unknown)."""

    rgb: tuple[float, float, float]
    area: float
    layout: tuple[float, float]


@dataclass
class Association:
    """Per frame and tracked body (N×B): the assigned blob's index (−1: missing), its colour
    cost, and the union of it and the blobs merged into it (``area``, ``core``, ``centroid``);
    per blob, the row that took it (``owner``, −1: none)."""

    blob: np.ndarray
    cost: np.ndarray
    area: np.ndarray
    core: np.ndarray
    centroid: np.ndarray
    owner: np.ndarray


def _predict(track: list, layout: np.ndarray, radius: float, diag: float):
    """The predicted position and its scale (see the module docstring)."""
    if len(track) >= 2 and track[-1][0] - track[-2][0] == 1:
        step = track[-1][1] - track[-2][1]
        return track[-1][1] + step, max(radius, 0.5 * float(np.hypot(*step)), POS_SIGMA_MIN)
    if track:
        return track[-1][1], max(2 * radius, POS_SIGMA_MIN)
    if np.isfinite(layout).all():
        return layout, max(diag / 8, POS_SIGMA_MIN)
    return None, 1.0


def associate(blobs: Blobs, n_frames: int, rows: list[Row], distractors, n_tracked: int,
              diag: float) -> Association:
    """Assign the scene's bodies (``rows``; the first ``n_tracked`` are the tracked ones, the
    others compete for blobs only) to the blobs of each frame (module docstring)."""
    n_b = n_tracked
    out = Association(np.full((n_frames, n_b), -1), np.full((n_frames, n_b), np.nan),
                      np.zeros((n_frames, n_b)), np.zeros((n_frames, n_b)),
                      np.full((n_frames, n_b, 2), np.nan), np.full(len(blobs), -1))
    if n_b == 0 or len(blobs) == 0:
        return out
    n_r = len(rows)
    blob_f = colour_features(blobs.rgb)
    cost_all = colour_cost(colour_features([r.rgb for r in rows]), blob_f)      # R×M
    if len(distractors):
        dis = colour_cost(colour_features(distractors), blob_f).min(axis=0)
    else:
        dis = np.full(len(blobs), np.inf)
    eligible = (cost_all <= COLOUR_GATE) & (cost_all <= dis + DISTRACTOR_MARGIN)
    expected = np.maximum(np.array([r.area for r in rows], float), 1.0)
    radius = np.sqrt(expected / math.pi)
    layout = np.array([r.layout for r in rows], float).reshape(n_r, 2)
    best_row = cost_all[:n_b].argmin(axis=0)
    neighbours: dict[int, list[int]] = {}
    for a, b in blobs.touching:
        neighbours.setdefault(int(a), []).append(int(b))
        neighbours.setdefault(int(b), []).append(int(a))
    order = np.argsort(blobs.frame, kind="stable")
    starts = np.searchsorted(blobs.frame[order], np.arange(n_frames + 1))
    tracks: list[list] = [[] for _ in range(n_r)]
    for k in range(n_frames):
        cols = order[starts[k]:starts[k + 1]]
        el = eligible[:, cols]
        if not el[:n_b].any():
            continue
        size = np.minimum(np.abs(np.log(blobs.area[cols][None, :] / expected[:, None]))
                          / math.log(2.0), SIZE_CAP)
        cost = cost_all[:, cols] ** 2 + size ** 2
        for r in range(n_r):
            at, sigma = _predict(tracks[r], layout[r], radius[r], diag)
            if at is not None:
                d = np.hypot(*(blobs.centroid[cols] - at).T) / sigma
                cost[r] += np.minimum(d, POS_CAP) ** 2
        # one private "missing" column per row: a body is missing rather than take a blob at a
        # higher cost (only when another body explains that blob better)
        full = np.full((n_r, len(cols) + n_r), np.inf)
        full[:, :len(cols)] = np.where(el, cost, np.inf)
        full[np.arange(n_r), len(cols) + np.arange(n_r)] = MISSING_COST
        rr, picks = linear_sum_assignment(full)
        chosen = {r: j for r, j in zip(rr, picks) if j < len(cols)}
        taken = {cols[j] for j in chosen.values()}
        for r, j in chosen.items():
            members = [cols[j]]
            if r < n_b:
                todo = [cols[j]]
                while todo:  # blobs of the body's drawn colour touching it (faces, pieces)
                    for j2 in neighbours.get(todo.pop(), ()):
                        if (j2 in members or j2 in taken or blobs.frame[j2] != k
                                or not eligible[r, j2] or best_row[j2] != r
                                or colour_cost(blob_f[[cols[j]]], blob_f[[j2]],
                                               math.inf)[0, 0] > MERGE_COST):
                            continue
                        members.append(j2)
                        todo.append(j2)
                taken.update(members)
            idx = np.array(members)
            out.owner[idx] = r
            area = blobs.area[idx]
            centroid = (blobs.centroid[idx] * area[:, None]).sum(0) / area.sum()
            tracks[r].append((k, centroid))
            if r < n_b:
                out.blob[k, r] = cols[j]
                out.cost[k, r] = cost_all[r, cols[j]]
                out.area[k, r] = area.sum()
                out.core[k, r] = blobs.core[idx].sum()
                out.centroid[k, r] = centroid
    return out
