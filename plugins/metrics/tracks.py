"""Object-track metrics: every dynamic body segmented by its colour in both clips, tracked by its
centroid, and compared frame by frame (family ``physics``, kind ``sequence``, lower is better).

Segmentation
------------
The bodies to track come from the ground-truth scene spec (``scene.spec``: ``bodies[]`` with
``id``, ``dynamic``, ``color_rgb``; the 2D background ``render.background_rgb``, the 3D floor
``world.floor.color_rgb``). Without a spec the scene's detection (``scene.detection``,
``objects[]``) is used and, PHYRE's convention, every object that is neither black nor purple
counts as dynamic. Without either, every metric is NaN.

* Tracked: each **dynamic body whose colour no other body shares** (and that differs from the
  background/floor). A dynamic body that shares its colour with another body cannot be told apart
  by colour: it is skipped, never tracked (``inp.extra["tracks"]["value"]["skipped"]``: id →
  why; ``["tracked"]``: the tracked ids), but its colour stays in the palette so its pixels are
  never given to another body. In the seed-0 benchmark 13 of 46 2D scenes have such bodies (31
  bodies: two green boxes, three blue boxes…); the red ball is always tracked.
* Every pixel is classified against the palette (every body colour, the background, the floor
  and, in 3D, the neutral grey axis) through a look-up table over the quantised RGB cube (5 bits
  a channel in 2D, 6 in 3D), each cell classified at its centre the first time a clip shows it:

  - 2D (``flat``: PHYRE's flat palette): the nearest palette colour in RGB, accepted within
    `FLAT_MAX_DIST` (90) RGB units. H.264 desaturates thin parts (a 10 px jar wall decodes some
    80 units away from its colour), hence the wide tolerance; the mixed colours of edges that
    land on another body's colour are removed by the erosion below.
  - 3D (``shaded``: three.js Lambert shading under white lights and neutral shadows scales a
    colour by a brightness factor): the nearest palette colour by the angle between RGB vectors
    (chromaticity), within `SHADED_MAX_ANGLE_DEG` (10°), for pixels whose largest channel is at
    least `SHADED_MIN_BRIGHTNESS` (24) and whose brightness factor relative to the colour is
    0.15–1.7. The sky, the floor and shadows are neutral and win on the neutral axis; black
    bodies are too dark to classify (never tracked, never confused). PHYRE's grey (185, 202, 210)
    is 3° off the neutral axis: enough on the benchmark's renders, the first colour to fail
    under heavy compression or tinted lights.
* Frames are classified on a regular sub-grid (every `stride`-th pixel: 2 at 512², 1 below
  512), a few frames at a time. A labelled sample is *core* if its four grid neighbours carry the
  same label (frame borders replicated, so a body cut by the border keeps its edge); the body is
  its core plus the samples of its colour touching the core (an opening by reconstruction): the
  one-sample fringes of mixed colour along other bodies' edges and isolated noise are dropped,
  the body's own outline is kept, so the centroid is not biased. Anything drawn thinner than
  about three grid steps (6 px at 512²) has no core and is not seen.
* Per body per frame: ``area`` (px of the full frame) and the centroid (continuous image
  coordinates, origin top-left, y down: pixel (i, j) is centred on (i + 0.5, j + 0.5)). The
  benchmark's H.264 references give the exact renders' visible-pixel centroids within 0.35 px on
  average (1.7 px at worst, a tilted jar) in 2D and the projected centres of 3D balls within
  1 px. A body is *present* when it has at least `MIN_SAMPLES` (4) core samples and an area of at
  least 3% of the largest area the reference shows for it; otherwise (outside the frame,
  occluded, not drawn, drawn in another colour) it is *missing*.

Limits: a body is found by its colour only. Anything else the generated video draws in a tracked
colour (text, a second object) is counted into that body's centroid; a body the model recolours
(even to a named colour near the one it was given, beyond the tolerance above) is *not found*.
Orientation is not tracked.

Metrics (each over the pairs of the `Alignment`: reference frame r_k with generated frame g_k)
----------------------------------------------------------------------------------------------
``track_pos_err`` (px)
    Mean over pairs k and tracked bodies b, counting each (k, b) where b is present in either
    frame, of the centroid distance; a body present in one frame and missing in the other counts
    as the frame diagonal D (725 px at 512²), the largest distance two visible centroids can be
    apart, so losing a body never scores better than drawing it anywhere.
``track_vel_err`` (px/s)
    Velocities by finite differences between consecutive pairs, each clip on its own clock
    (v = Δcentroid / (Δframe / fps)); mean over intervals and bodies of ‖v_ref − v_gen‖. An
    interval where a body is seen at both ends in one clip only counts as ‖v‖ + D / T (T: the
    clip's duration, (n − 1) / fps), more than any visible motion at rest would.
``event_contact_err`` (s)
    Per body, the first time its motion changes abruptly (a collision, the start of a push or a
    fall): the first interval where the change of acceleration between successive frame triples,
    expressed as a displacement (‖Δa‖·h², h the mean frame gap in seconds: the third difference
    of the positions on an even grid), exceeds max(`CONTACT_PX_MIN`,
    `CONTACT_DIAG_FRACTION`·D) = max(4 px, 0.6% of D) (4.3 px at 512²; centroid noise gives
    ≤ 3 px); free flight, resting and rolling down a straight ramp have constant acceleration,
    so they never fire. Windows where the body's area changes by more
    than 1.6× (occlusion, leaving the frame) are skipped. Time: the middle of the interval the
    change falls in. Four frames are needed, so a change in the first two intervals is reported
    in the third (0.5 s in a 5 fps clip), the same in both clips.
``event_rest_err`` (s)
    Per body that moved (speed ≥ 3× the threshold at some point) and is present in the last
    paired frame: the start of the final run of intervals with speed < `REST_PX_PER_FRAME` (1 px
    per frame of the clip, i.e. fps px/s) lasting to the end of the clip.
``event_exit_err`` (s)
    Per body: the first paired frame after which it is missing for the rest of the clip, having
    been present before and last seen within reach of the frame border (its equivalent radius
    plus its last step plus 2 px).

Event times are read on the reference's clock of the pairs (τ_k = r_k / fps, also for the
generated clip's events), so the aligned pairings measure timing after the shift they applied.
Each event metric is the mean over the bodies that have the event in either clip of
|t_ref − t_gen|; an event in one clip only counts as the clip duration T. No event in either clip
for any body: 0 (the clips agree). Every metric is NaN when no tracked body is present in any
frame of the reference (nothing to compare against) or there are no pairs (fewer than two for
the velocity).

Segmentation runs once per clip and scene (``inp.extra["tracks"]``, shared by the metrics and
the three pairings).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from visphy_core.hookspecs import hookimpl
from visphy_core.metrics import LOWER, SEQUENCE, Metric, MetricInput

FLAT_MAX_DIST = 90.0            # RGB units, 2D
SHADED_MAX_ANGLE_DEG = 10.0     # degrees between RGB vectors, 3D
SHADED_MIN_BRIGHTNESS = 24      # max channel, 3D: darker pixels have no reliable chromaticity
SHADED_SCALE = (0.15, 1.7)      # brightness factor of a pixel relative to its palette colour
FLAT_MIN_SEPARATION = 30.0      # RGB units: two colours closer than this are "shared" (2D)
SHADED_MIN_SEPARATION_DEG = 2.0  # degrees: same, 3D (chromaticity)
PRESENT_FRACTION = 0.03         # of the body's largest area in the reference
MIN_SAMPLES = 4                 # grid samples a present body needs at least
CONTACT_PX_MIN, CONTACT_DIAG_FRACTION = 4.0, 0.006  # change of motion that counts as contact
AREA_JUMP = 1.6                 # area ratio within a contact window that voids it
REST_PX_PER_FRAME = 1.0         # below this speed (px per frame of the clip) a body is still
MOVED_FACTOR = 3.0              # a body comes to rest only if it once moved 3× faster

_STATIC_PHYRE = ((0, 0, 0), (75, 74, 164))  # black and purple: static in PHYRE's palette
_NEUTRAL = (1.0, 1.0, 1.0)


# ------------------------------------------------------------------------------ the palette
@dataclass(frozen=True)
class Palette:
    """What to look for in a scene's clips: the tracked bodies (label k + 1 for ``ids[k]``) and
    every other colour that must not be mistaken for them."""

    mode: str                                   # "flat" (2D) or "shaded" (3D)
    ids: tuple[str, ...]                        # tracked body ids
    tracked: tuple[tuple[int, int, int], ...]   # their colours
    others: tuple[tuple[int, int, int], ...]    # background, floor, other bodies
    skipped: tuple[tuple[str, str], ...] = ()   # (dynamic body id, why it is not tracked)

    @property
    def bits(self) -> int:
        return 5 if self.mode == "flat" else 6


def _rgb(value) -> tuple[int, int, int] | None:
    try:
        r, g, b = (int(round(float(v))) for v in list(value)[:3])
    except (TypeError, ValueError):
        return None
    return (min(max(r, 0), 255), min(max(g, 0), 255), min(max(b, 0), 255))


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        return 0.0 if na == nb else 90.0
    return math.degrees(math.acos(min(1.0, max(-1.0, float(a @ b) / (na * nb)))))


def _same_colour(mode: str, a, b) -> bool:
    if mode == "flat":
        return float(np.linalg.norm(np.subtract(a, b, dtype=float))) < FLAT_MIN_SEPARATION
    if max(a) < SHADED_MIN_BRIGHTNESS or max(b) < SHADED_MIN_BRIGHTNESS:
        return max(a) < SHADED_MIN_BRIGHTNESS and max(b) < SHADED_MIN_BRIGHTNESS
    return _angle_deg(a, b) < SHADED_MIN_SEPARATION_DEG


def scene_palette(scene) -> Palette | None:
    """The palette of a scene from its spec (else its detection); None without either."""
    try:
        spec = scene.spec
    except Exception:  # noqa: BLE001 - an unreadable spec: fall back to the detection
        spec = None
    bodies: list[tuple[str, tuple[int, int, int], bool]] = []
    backgrounds: list[tuple[int, int, int]] = []
    dim = getattr(scene, "dim", "2d")
    if isinstance(spec, dict) and isinstance(spec.get("bodies"), list):
        dim = spec.get("dim", dim)
        for b in spec["bodies"]:
            rgb = _rgb(b.get("color_rgb")) if isinstance(b, dict) else None
            if rgb is not None:
                bodies.append((str(b.get("id")), rgb, bool(b.get("dynamic"))))
        bg = _rgb((spec.get("render") or {}).get("background_rgb"))
        backgrounds.append(bg or (255, 255, 255))
        floor = _rgb(((spec.get("world") or {}).get("floor") or {}).get("color_rgb"))
        if floor is not None:
            backgrounds.append(floor)
    else:
        try:
            det = scene.detection
        except Exception:  # noqa: BLE001
            det = None
        if not isinstance(det, dict) or not isinstance(det.get("objects"), list):
            return None
        for o in det["objects"]:
            rgb = _rgb(o.get("color_rgb")) if isinstance(o, dict) else None
            if rgb is not None:
                bodies.append((str(o.get("id")), rgb, rgb not in _STATIC_PHYRE))
        backgrounds.append((255, 255, 255))
    mode = "shaded" if dim == "3d" else "flat"
    ids, tracked, others, skipped = [], [], list(backgrounds), []
    for i, (bid, rgb, dynamic) in enumerate(bodies):
        if not dynamic:
            others.append(rgb)
            continue
        clash = [o for j, (o, c, _) in enumerate(bodies) if j != i and _same_colour(mode, rgb, c)]
        if mode == "shaded" and max(rgb) < SHADED_MIN_BRIGHTNESS:
            skipped.append((bid, "too dark to segment by chromaticity"))
            others.append(rgb)
        elif clash:
            skipped.append((bid, f"shares its colour with {', '.join(clash)}"))
            others.append(rgb)
        elif any(_same_colour(mode, rgb, c) for c in backgrounds) or (
                mode == "shaded" and _angle_deg(rgb, _NEUTRAL) < SHADED_MIN_SEPARATION_DEG):
            skipped.append((bid, "its colour is the background's"))
        else:
            ids.append(bid)
            tracked.append(rgb)
    return Palette(mode=mode, ids=tuple(ids), tracked=tuple(tracked),
                   others=tuple(dict.fromkeys(others)), skipped=tuple(skipped))


def classify(palette: Palette, rgb: np.ndarray) -> np.ndarray:
    """Label of each colour of an M×3 array (0: none, k + 1: tracked body k)."""
    cube = np.asarray(rgb, dtype=np.float32).reshape(-1, 3)
    cols = np.array(palette.tracked + palette.others, dtype=np.float32).reshape(-1, 3)
    n_tracked = len(palette.tracked)
    if len(cube) == 0:
        return np.zeros(0, np.uint8)
    if palette.mode == "flat":
        d2 = ((cube[:, None, :] - cols[None, :, :]) ** 2).sum(-1)
        best = d2.argmin(1)
        ok = d2[np.arange(len(cube)), best] <= FLAT_MAX_DIST ** 2
    else:
        chroma = np.concatenate([cols, np.array([_NEUTRAL], np.float32)])
        bright = chroma.max(1) >= SHADED_MIN_BRIGHTNESS
        bright[-1] = True
        unit = chroma / np.maximum(np.linalg.norm(chroma, axis=1, keepdims=True), 1e-6)
        norm = np.maximum(np.linalg.norm(cube, axis=1, keepdims=True), 1e-6)
        cos = (cube / norm) @ unit.T
        cos[:, ~bright] = -2.0  # black/dark colours have no chromaticity
        best = cos.argmax(1)
        cbest = cos[np.arange(len(cube)), best]
        scale = (cube * chroma[best]).sum(1) / np.maximum((chroma[best] ** 2).sum(1), 1e-6)
        ok = ((cbest >= math.cos(math.radians(SHADED_MAX_ANGLE_DEG)))
              & (cube.max(1) >= SHADED_MIN_BRIGHTNESS)
              & (scale >= SHADED_SCALE[0]) & (scale <= SHADED_SCALE[1]))
    return np.where(ok & (best < n_tracked), best + 1, 0).astype(np.uint8)


@lru_cache(maxsize=64)
def _lut(palette: Palette) -> tuple[np.ndarray, np.ndarray]:
    """The look-up table over the quantised RGB cube (label per cell) and which cells are
    filled in: cells are classified the first time a clip shows them (`_fill`)."""
    size = 1 << (3 * palette.bits)
    return np.zeros(size, np.uint8), np.zeros(size, bool)


def _fill(palette: Palette, keys: np.ndarray) -> np.ndarray:
    """The table with every cell in ``keys`` classified (at the cell's centre)."""
    lut, done = _lut(palette)
    bits = palette.bits
    miss = ~done[keys]
    if miss.any():
        todo = np.unique(keys[miss]).astype(np.int64)
        mask = (1 << bits) - 1
        q = np.stack([(todo >> (2 * bits)) & mask, (todo >> bits) & mask, todo & mask], axis=1)
        centre = q * float(1 << (8 - bits)) + ((1 << (8 - bits)) - 1) / 2.0
        lut[todo] = classify(palette, centre)
        done[todo] = True
    return lut


# ---------------------------------------------------------------------------- segmentation
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
    bits, sh = palette.bits, 8 - palette.bits
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
        key = (g[..., 0] >> sh).astype(np.uint32)
        key <<= bits
        key |= g[..., 1] >> sh
        key <<= bits
        key |= g[..., 2] >> sh
        lab[:m, 1:-1, 1:-1] = _fill(palette, key)[key]
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
    and generated `Tracks`, presence masks, the skipped bodies. None without a palette."""
    key = (id(inp.reference), id(inp.generated))
    memo = inp.extra.get("tracks")
    if memo is not None and memo.get("key") == key:
        return memo["value"]
    palette = scene_palette(inp.scene)
    if palette is None:
        value = None
    else:
        ref = segment(inp.reference, palette)
        gen = segment(inp.generated, palette)
        floor = MIN_SAMPLES * ref.stride ** 2
        min_area = np.maximum(floor, PRESENT_FRACTION * ref.area.max(axis=0, initial=0.0))
        value = {"palette": palette, "ref": ref, "gen": gen,
                 "ref_present": (ref.area >= min_area) & (ref.core >= floor),
                 "gen_present": (gen.area >= min_area) & (gen.core >= floor),
                 "max_area": ref.area.max(axis=0, initial=0.0),
                 "skipped": dict(palette.skipped), "tracked": list(palette.ids)}
    inp.extra["tracks"] = {"key": key, "value": value}
    return value


# ------------------------------------------------------------------------------- kinematics
def _clip_consts(inp: MetricInput) -> tuple[float, float, float]:
    """(fps, frame diagonal D in px, clip duration T in s) of the reference clip."""
    fps = float(getattr(inp.scene.clip, "fps", 0.0) or 0.0)
    fps = fps if fps > 0 else 1.0
    h, w = inp.reference.shape[1:3]
    return fps, float(math.hypot(h, w)), max(len(inp.reference) - 1, 1) / fps


def _velocities(c: np.ndarray, p: np.ndarray, frames: np.ndarray, fps: float):
    """Interval velocities (K−1×B×2, px/s, NaN where undefined) between the clip's frames
    ``frames`` (K indices) and whether each is defined (the body present at both ends, a
    positive time step)."""
    dt = np.diff(frames) / fps
    ok = p[1:] & p[:-1] & (dt[:, None] > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = (c[1:] - c[:-1]) / np.where(dt > 0, dt, np.nan)[:, None, None]
    return np.where(ok[..., None], v, np.nan), ok


def _first(fire: np.ndarray, times: np.ndarray) -> list[float | None]:
    """Per column of a K×B bool array, the time of its first True (None: never)."""
    if fire.shape[0] == 0:
        return [None] * fire.shape[1]
    first = fire.argmax(axis=0)
    return [float(times[k]) if fire[k, b] else None for b, k in enumerate(first)]


def contact_times(c, p, area, frames, fps, tau, contact_px: float) -> list[float | None]:
    """Per body: the first abrupt change of acceleration (see the module docstring)."""
    k_n, n_b = p.shape
    if k_n < 4:
        return [None] * n_b
    v, vok = _velocities(c, p, frames, fps)
    dt = np.diff(frames) / fps
    with np.errstate(invalid="ignore", divide="ignore"):
        acc = (v[1:] - v[:-1]) / ((dt[1:] + dt[:-1]) / 2)[:, None, None]
        jump = np.linalg.norm(acc[1:] - acc[:-1], axis=-1)            # K−3 × B
    h = (dt[:-2] + dt[1:-1] + dt[2:]) / 3
    ok = vok[:-2] & vok[1:-1] & vok[2:]
    win = np.lib.stride_tricks.sliding_window_view(area, 4, axis=0)   # K−3 × B × 4
    lo, hi = win.min(axis=-1), win.max(axis=-1)
    steady = (lo > 0) & (hi <= AREA_JUMP * lo)
    fire = ok & steady & (np.nan_to_num(jump) * (h * h)[:, None] > contact_px)
    # the change first seen on frames k..k+3 happened in the interval (k+2, k+3)
    return _first(fire, (tau[2:-1] + tau[3:]) / 2)


def rest_times(c, p, frames, fps, tau, rest_speed: float) -> list[float | None]:
    """Per body that moved and is seen in the last frame: the start of the still run that lasts
    to the end of the clip."""
    k_n, n_b = p.shape
    out: list[float | None] = [None] * n_b
    if k_n < 2:
        return out
    v, vok = _velocities(c, p, frames, fps)
    speed = np.linalg.norm(np.nan_to_num(v), axis=-1)
    for b in range(n_b):
        idx = np.flatnonzero(vok[:, b])
        if not p[-1, b] or len(idx) == 0:
            continue
        moving = idx[speed[idx, b] >= rest_speed]
        if len(moving) == 0 or speed[moving, b].max() < MOVED_FACTOR * rest_speed:
            continue
        after = idx[idx > moving[-1]]
        if len(after):  # else still moving at the end
            out[b] = float(tau[after[0]])
    return out


def exit_times(c, p, area, max_area, tau, size) -> list[float | None]:
    """Per body: the first frame after which it stays missing, last seen at the border."""
    k_n, n_b = p.shape
    out: list[float | None] = [None] * n_b
    h, w = size
    for b in range(n_b):
        seen = np.flatnonzero(p[:, b])
        if len(seen) == 0 or seen[-1] == k_n - 1:
            continue
        last = seen[-1]
        x, y = c[last, b]
        radius = math.sqrt(max(max_area[b], area[last, b]) / math.pi)
        step = float(np.linalg.norm(c[last, b] - c[last - 1, b])) \
            if last > 0 and p[last - 1, b] else 0.0
        if min(x, y, w - x, h - y) <= radius + step + 2.0:
            out[b] = float(tau[last + 1])
    return out


def _event_error(ref: list, gen: list, duration: float) -> float:
    errs = [abs(a - b) if a is not None and b is not None else duration
            for a, b in zip(ref, gen) if a is not None or b is not None]
    return float(np.mean(errs)) if errs else 0.0


NAMES = ("track_pos_err", "track_vel_err", "event_contact_err", "event_rest_err",
         "event_exit_err")


def _paired(inp: MetricInput, alignment) -> dict | None:
    """Both clips' observations on the pairs, with each clip's clock and the pairs' clock."""
    st = scene_tracks(inp)
    if st is None:
        return None
    ri = np.asarray(alignment.ref_idx, dtype=np.int64)
    gi = np.asarray(alignment.gen_idx, dtype=np.int64)
    fps, diag, duration = _clip_consts(inp)
    out = {"st": st, "fps": fps, "diag": diag, "duration": duration, "n": len(ri)}
    for name, idx in (("ref", ri), ("gen", gi)):
        tr = st[name]
        out[name] = {"c": tr.centroid[idx], "p": st[f"{name}_present"][idx], "a": tr.area[idx],
                     "frames": idx, "tau": ri / fps}
    return out


def _events(d: dict, side: dict, size) -> dict[str, list]:
    fps, diag = d["fps"], d["diag"]
    contact_px = max(CONTACT_PX_MIN, CONTACT_DIAG_FRACTION * diag)
    c, p, a, f, tau = side["c"], side["p"], side["a"], side["frames"], side["tau"]
    return {"contact": contact_times(c, p, a, f, fps, tau, contact_px),
            "rest": rest_times(c, p, f, fps, tau, REST_PX_PER_FRAME * fps),
            "exit": exit_times(c, p, a, d["st"]["max_area"], tau, size)}


def track_events(inp: MetricInput, alignment) -> dict[str, dict[str, list]]:
    """The event times each clip shows under a pairing, for inspection: ``{"ref"|"gen":
    {"contact"|"rest"|"exit": [seconds or None per tracked body]}}`` (the pairs' clock)."""
    d = _paired(inp, alignment)
    if d is None:
        return {}
    size = inp.reference.shape[1:3]
    return {name: _events(d, d[name], size) for name in ("ref", "gen")}


def track_values(inp: MetricInput, alignment) -> dict[str, float]:
    """The five values under one pairing (memoised per pairing in ``inp.extra``)."""
    memo = inp.extra.setdefault("tracks.values", {})
    mkey = (id(inp.reference), id(inp.generated),
            np.asarray(alignment.ref_idx, dtype=np.int64).tobytes(),
            np.asarray(alignment.gen_idx, dtype=np.int64).tobytes())
    if mkey not in memo:
        memo[mkey] = _track_values(inp, alignment)
    return memo[mkey]


def _track_values(inp: MetricInput, alignment) -> dict[str, float]:
    out = dict.fromkeys(NAMES, float("nan"))
    d = _paired(inp, alignment)
    if d is None or d["n"] == 0 or not d["st"]["ref_present"].any():
        return out
    diag, duration = d["diag"], d["duration"]
    ref, gen = d["ref"], d["gen"]
    pr, pg = ref["p"], gen["p"]

    either = pr | pg
    dist = np.where(pr & pg, np.linalg.norm(np.nan_to_num(ref["c"] - gen["c"]), axis=-1), diag)
    out["track_pos_err"] = float(dist[either].mean()) if either.any() else 0.0

    if d["n"] >= 2:
        vr, okr = _velocities(ref["c"], pr, ref["frames"], d["fps"])
        vg, okg = _velocities(gen["c"], pg, gen["frames"], d["fps"])
        pen = diag / duration
        sr = np.linalg.norm(np.nan_to_num(vr), axis=-1)
        sg = np.linalg.norm(np.nan_to_num(vg), axis=-1)
        err = np.where(okr & okg, np.linalg.norm(np.nan_to_num(vr - vg), axis=-1),
                       np.where(okr, sr, sg) + pen)
        sel = okr | okg
        out["track_vel_err"] = float(err[sel].mean()) if sel.any() else 0.0

    size = inp.reference.shape[1:3]
    er, eg = _events(d, ref, size), _events(d, gen, size)
    for kind in ("contact", "rest", "exit"):
        out[f"event_{kind}_err"] = _event_error(er[kind], eg[kind], duration)
    return out


# --------------------------------------------------------------------------------- metrics
class _TrackMetric(Metric):
    direction = LOWER
    family = "physics"
    kind = SEQUENCE
    needs = ("frames", "scene_spec")
    version = "1"
    score_range = (0.0, float("inf"))

    details_key = "tracks"

    def details(self, inp: MetricInput) -> dict:
        """Which dynamic bodies were tracked, and which were skipped and why."""
        palette = scene_palette(inp.scene)
        if palette is None:
            return {"tracked": [], "skipped": {},
                    "note": "no ground-truth spec or detection: nothing to track"}
        return {"tracked": list(palette.ids), "skipped": dict(palette.skipped)}

    def compute_sequence(self, inp: MetricInput, alignment) -> float:
        return track_values(inp, alignment)[self.name]


class TrackPosErr(_TrackMetric):
    """Mean centroid distance of the tracked bodies over the paired frames (px)."""
    name = "track_pos_err"


class TrackVelErr(_TrackMetric):
    """Mean error of the tracked bodies' finite-difference velocities (px/s)."""
    name = "track_vel_err"


class EventContactErr(_TrackMetric):
    """Mean |Δt| of each body's first abrupt change of motion (s)."""
    name = "event_contact_err"


class EventRestErr(_TrackMetric):
    """Mean |Δt| of the time each body comes to rest for good (s)."""
    name = "event_rest_err"


class EventExitErr(_TrackMetric):
    """Mean |Δt| of the time each body leaves the frame (s)."""
    name = "event_exit_err"


METRICS = (TrackPosErr, TrackVelErr, EventContactErr, EventRestErr, EventExitErr)


@hookimpl
def visphy_register_metrics(register):
    for cls in METRICS:
        register(cls())
