"""Object-track metrics: every dynamic body of the ground truth found in both clips, tracked by
its centroid, and compared frame by frame (family ``physics``, kind ``sequence``, lower is
better). The reference is segmented by its exact palette; in the generated clip colour is a cue,
not a gate (models draw the palette paler, tinted, shaded, anti-aliased or outlined).

Which bodies
------------
The bodies to track come from the ground-truth scene spec (``scene.spec``: ``bodies[]`` with
``id``, ``dynamic``, ``color_rgb``; the 2D background ``render.background_rgb``, the 3D floor
``world.floor.color_rgb``). Without a spec the scene's detection (``scene.detection``,
``objects[]``: the original layout) is used and, PHYRE's convention, every object that is
neither black nor purple counts as dynamic. Without either, every metric is NaN.

* Tracked: each **dynamic body whose colour no other body shares** (and that differs from the
  background/floor). A dynamic body that shares its colour with another body cannot be told apart
  by colour in the reference: it is skipped, never tracked (``inp.extra["tracks"]["value"]
  ["skipped"]``: id → why; ``["tracked"]``: the tracked ids), but its colour stays in the palette
  so its pixels are never given to another body. In the seed-0 benchmark 13 of 46 2D scenes have
  such bodies (31 bodies: two green boxes, three blue boxes…); the red ball is always tracked.

The reference: the exact palette
--------------------------------
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
  occluded, not drawn) it is *missing*.

The generated clip: colour-tolerant association
-----------------------------------------------
`plugins/metrics/association.py` has the details and the constants.

* **Blobs without the palette**: foreground is every sample farther than ΔE 6 (CIELAB) from
  each background colour (the scene's, plus any colour covering 12% of the clip's first, middle
  or last frame: a model's own background or floor); neighbouring foreground samples join when
  their colours differ by less than ΔE 12 and 6° of chromaticity (a shaded sphere stays one blob;
  a body and its outline, or two touching bodies, do not); a blob whose interior holds two groups
  of chromaticity (two bodies joined through a blurred edge) is cut again with stricter
  thresholds. The core/erosion rule above applies to blobs; blobs over 20% of the frame are
  backgrounds.
* **Colour cost** between a body's colour and a blob's mean colour: the hue of the component
  orthogonal to RGB's grey axis (unchanged by mixing with white or by shading), the logarithm of
  the saturation and L*, in gate units: on the benchmark's palette a 50% paler colour costs
  0.5–1.3, a hue turned 15° 0.3–0.65, the shaded 3D spheres ≈ 0.25, PHYRE's red against its grey
  4.0; a pair beyond 1.75 (e.g. red drawn magenta, ≈ 60° of hue) never matches.
* **Assignment**, frame by frame, of every body of the scene — the tracked ones, and the
  detection's other objects (static, colour-sharing), so that each keeps the blob it explains —
  to the blobs by one min-cost assignment (`scipy.optimize.linear_sum_assignment`) over colour²
  + size² (|ln area ratio| / ln 2, capped at 1.5; expected: the reference's largest area) +
  position² (distance to the position predicted from the body's last two positions in the
  generated clip, or its first position in the reference, over its radius or half its last step,
  capped at 1.5, so a body that moves wrongly is still found); a body whose only candidates
  another body explains better stays *missing*. Touching blobs of the body's drawn colour
  (lightness aside: the faces of a shaded box) join it.
* **Which measurement**: the palette segmentation of the generated clip where it finds the body
  and agrees with the association (centroids within 0.1 of the blob's radius + 2 samples, the
  palette seeing at least 80% of the blob's area) in at least half the frames where both find
  it — identical clips still score exactly 0 — the associated blobs otherwise; a palette region
  lying mostly in blobs the association gave to other bodies is not the body. ``gen_source``
  (N×B: 0 not found, 1 palette, 2 association) and ``gen_colour_cost`` record which, per frame.

On the mini benchmark's four 2D scenes re-rendered with a 50% paler palette (and a hue turned
±15°), synthetic Lambert shading or H.264 re-encoding of those, ``track_pos_err`` stays within
1 px of the exact oracle's (0); a body removed from such a clip is missing in every frame. On
the 3D scenes of templates 3 and 10, re-rendered by three.js with a 50% paler palette, it stays
within 0.5 px of the exact render's (which is 0.5–0.7 px from the H.264 reference).

Limits: thin parts (jar walls, bars about 10 px wide) drawn with an outline *and* a pale
palette lose their interior samples; the body is then its thicker part (a jar's base). Bodies
that share a colour are not tracked (the reference cannot tell them apart). In 3D, a grey body
on the grey floor may merge into it. Orientation is not tracked.

Metrics (each over the pairs of the `Alignment`: reference frame r_k with generated frame g_k)
----------------------------------------------------------------------------------------------
``track_pos_err`` (px)
    Mean over pairs k and tracked bodies b, counting each (k, b) where b is present in either
    frame, of the centroid distance; a body present in one frame and missing in the other costs
    a fixed, bounded `MISSING_DIAG_FRACTION` of the frame diagonal D: P = D / 4 (181 px at
    512²), never the whole diagonal (a body the tracker cannot find is no evidence of a path
    farther off than any drawn one); a blank clip scores P.
``track_vel_err`` (px/s)
    Velocities by finite differences between consecutive pairs, each clip on its own clock
    (v = Δcentroid / (Δframe / fps)); mean over intervals and bodies of ‖v_ref − v_gen‖. An
    interval where a body is seen at both ends in one clip only counts as ‖v‖ + P / T (T: the
    clip's duration, (n − 1) / fps).
``event_contact_err`` (s)
    Per body, the first time its motion changes abruptly (a collision, the start of a push or a
    fall). Found on the frames: the first window of four frames k..k+3 where the change of
    acceleration between successive frame triples, expressed as a displacement (‖Δa‖·h², h the
    mean frame gap in seconds: the third difference of the positions on an even grid), exceeds
    max(`CONTACT_PX_MIN`, `CONTACT_DIAG_FRACTION`·D) = max(4 px, 0.6% of D) (4.3 px at 512²;
    centroid noise gives ≤ 3 px); free flight, resting and rolling down a straight ramp have
    constant acceleration, so they never fire. Windows where the body's area changes by more
    than 1.6× (occlusion, leaving the frame) are skipped. Timed between the frames: a change
    first seen on frames k..k+3 happened in (k, k+1), (k+1, k+2) or (k+2, k+3). For each of the
    three, the body's track around it (up to `CONTACT_FIT_BEFORE` (4) frames before k and up to
    frame k + `CONTACT_FIT_AFTER` (6), while present with a steady area) is fitted by least
    squares, per axis, with two constant-acceleration pieces, one before a break time τ and one
    after it, that meet at τ (the position is continuous, the velocity jumps); τ is searched
    over the interval (`kink_time`: coarse to fine, ≈1e-4 of a frame). Each piece has an
    acceleration of its own when both have at least `OWN_ACC_POINTS` (4) frames; otherwise
    they share one (free flight before and after a bounce), and a piece of one frame is still.
    The interval with the smallest residual wins, but an earlier one only with less than
    `EARLIER_RESIDUAL` (¼) of a later one's: a strong change fires on the first window that
    holds it, so it is most often in the window's last interval, and a track the two pieces
    cannot follow (a second collision among the frames fitted, common at 5 fps) leaves every
    interval a large residual. On noise-free tracks made of two such pieces the time is exact
    (a bounce anywhere; different accelerations once four frames either side are seen) and
    inside the interval the change is in; with 0.3 px of centroid noise it is within ≈0.02 s
    at 5 fps. A second change of motion within the frames fitted biases it, within the three
    intervals the window allows. In the 2D clips of the validity study
    (benchmarks/validity_study.py), a detected first contact's time lies within 0.05 s of the
    step where Box2D first changed the body's velocity abruptly in 59% of the 259 contacts,
    within 0.2 s in 84% (the middle of the window's last interval, the time before: 41%,
    80%). The time moves continuously with the motion, not in steps of a frame.
``event_rest_err`` (s)
    Per body that moved (speed ≥ 3× the threshold at some point) and is present in the last
    paired frame: the time its speed falls below `REST_PX_PER_FRAME` (1 px per frame of the
    clip, i.e. fps px/s) for good. Each interval's speed is placed at the interval's middle;
    the time is interpolated linearly between the middles of the last interval at or above the
    threshold and of the first interval of the final run below it that lasts to the end of the
    clip (exact while the speed changes linearly across the two intervals).
``event_exit_err`` (s)
    Per body that is missing for the rest of the clip after a last frame it is present in,
    having been present before and last seen within reach of the frame border (its equivalent
    radius plus its last step plus 2 px): the time it has wholly left the frame. The body's
    centre follows a constant-acceleration path through its last ≤ 3 frames seen whole (area
    ≥ `EXIT_WHOLE_FRACTION` (90%) of its largest; otherwise its last ≤ 3 frames), extrapolated
    to where the centre lies one equivalent radius √(area/π) beyond an edge; the time is kept
    within the interval after the last frame it is present in (the frame after it when the
    path does not leave).

Event times are read on the reference's clock of the pairs (τ_k = r_k / fps, also for the
generated clip's events), so the aligned pairings measure timing after the shift they applied;
each clip's fits use its own frame times, and a time between two pairs is placed linearly
between their τ.
Each event metric is the mean over the bodies that have the event in either clip of
|t_ref − t_gen|; an event in one clip only counts as the clip duration T. No event in either clip
for any body: 0 (the clips agree). Every metric is NaN when no tracked body is present in any
frame of the reference (nothing to compare against) or there are no pairs (fewer than two for
the velocity).

Segmentation runs once per clip and scene (``inp.extra["tracks"]``, shared by the metrics and
the three pairings).
"""
# size: one tracker: segmentation, association and the track errors share one data model

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import LOWER, SEQUENCE, Metric, MetricInput
from visphy_plugins.metrics.association import Row, associate, dominant_colours, find_blobs

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
CONTACT_FIT_BEFORE, CONTACT_FIT_AFTER = 4, 6  # frames around a contact its sub-frame fit uses
OWN_ACC_POINTS = 4              # points a piece needs for an acceleration of its own
KINK_GRID, KINK_LEVELS = 16, 4  # the break search: points per level, levels (≈1e-4 frame)
EARLIER_RESIDUAL = 0.25  # an earlier interval must fit this much better than a later one
EXIT_WHOLE_FRACTION = 0.9       # of its largest area: a body not cut by the frame border
MISSING_DIAG_FRACTION = 0.25    # a body seen in one clip only: a quarter of the diagonal
AGREE_RADIUS_FRACTION, AGREE_PX = 0.1, 2.0  # palette and association agree: centroids...
AGREE_AREA_RATIO = 0.8                      # ...and the palette sees most of the blob...
AGREE_FRAMES = 0.5                          # ...in this fraction of the frames

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
    background: tuple[tuple[int, int, int], ...] = ()  # background (and 3D floor) colours

    @property
    def distractors(self) -> tuple[tuple[int, int, int], ...]:
        """The other bodies' colours (static, shared, too dark): not the background's."""
        return tuple(c for c in self.others if c not in self.background)

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
                   others=tuple(dict.fromkeys(others)), skipped=tuple(skipped),
                   background=tuple(dict.fromkeys(backgrounds)))


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


def _first(fire: np.ndarray) -> list[int | None]:
    """Per column of a K×B bool array, the row of its first True (None: never)."""
    if fire.shape[0] == 0:
        return [None] * fire.shape[1]
    first = fire.argmax(axis=0)
    return [int(k) if fire[k, b] else None for b, k in enumerate(first)]


def _pairs_time(tau: np.ndarray, ends, i: int, t: float) -> float:
    """A time ``t`` of a clip's own clock between its frames i and i + 1 (``ends``: their
    times on that clock) on the pairs' clock: linear between τ_i and τ_{i+1}, clamped."""
    span = ends[1] - ends[0]
    f = min(1.0, max(0.0, (t - ends[0]) / span)) if span > 0 else 0.0
    return float(tau[i] + f * (tau[i + 1] - tau[i]))


def _piecewise_cost(t: np.ndarray, y: np.ndarray, n_pre: int, breaks: np.ndarray,
                    h: float) -> np.ndarray:
    """For each break time τ in ``breaks``: the residual sum of squares (px²) of the best
    continuous least-squares fit of the positions ``y`` (n×2) at times ``t`` by one polynomial
    per axis before τ (the first ``n_pre`` points) and another after it, meeting at τ. Each
    piece has constant acceleration: its own when both pieces have `OWN_ACC_POINTS` points or
    more (a piece fitted exactly by its own parabola could swallow a point of the other side
    unnoticed); otherwise one shared by both (free flight before and after a bounce); a piece
    of one point is still."""
    u = (t[None, :] - breaks[:, None]) / h                      # G×n, in frame gaps
    pre = np.arange(len(t)) < n_pre
    n_post = len(t) - n_pre
    cols = [np.ones_like(u)]  # the shared position at τ: the two pieces meet
    if n_pre >= 2:
        cols.append(np.where(pre, u, 0.0))
    if n_post >= 2:
        cols.append(np.where(pre, 0.0, u))
    if n_pre >= OWN_ACC_POINTS and n_post >= OWN_ACC_POINTS:
        cols += [np.where(pre, u * u, 0.0), np.where(pre, 0.0, u * u)]
    else:
        moving = (pre & (n_pre >= 2)) | (~pre & (n_post >= 2))
        cols.append(np.where(moving, u * u, 0.0))
    x = np.stack(cols, axis=-1)                                  # G×n×m
    xt = np.swapaxes(x, 1, 2)
    gram = xt @ x
    gram += 1e-12 * np.eye(len(cols)) * np.trace(gram, axis1=1, axis2=2)[:, None, None]
    r = y - x @ np.linalg.solve(gram, xt @ y)
    return (r * r).sum(axis=(1, 2))


def kink_time(t: np.ndarray, y: np.ndarray, n_pre: int) -> tuple[float, float]:
    """The break (τ, residual px²) of the best continuous two-piece constant-acceleration fit
    of a track whose change of motion lies between its points ``n_pre − 1`` and ``n_pre``
    (``t``: times, ``y``: n×2 positions): a coarse-to-fine search (`KINK_GRID` points,
    `KINK_LEVELS` times) over that interval, exact to ~1e-4 of it on noise-free parabolas."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    a, b = float(t[n_pre - 1]), float(t[n_pre])
    h = float(np.mean(np.diff(t)))
    lo, hi = a, b
    for _ in range(KINK_LEVELS):
        grid = np.linspace(lo, hi, KINK_GRID + 1)
        cost = _piecewise_cost(t, y, n_pre, grid, h)
        j = int(np.argmin(cost))
        step = (hi - lo) / KINK_GRID
        lo, hi = max(a, grid[j] - step), min(b, grid[j] + step)
    return float(grid[j]), float(cost[j])


def _contact_time(c, p, area, frames, fps: float, tau, k: int) -> float:
    """Sub-frame time of a change of motion first seen on frames k..k+3 (see the module
    docstring): it lies in one of the intervals (k, k+1), (k+1, k+2), (k+2, k+3); each is
    tried with the frames around (the steady ones, `CONTACT_FIT_BEFORE` before k and up to
    k + `CONTACT_FIT_AFTER`), latest first; an earlier interval wins when its continuous
    two-piece fit leaves less than `EARLIER_RESIDUAL` of the best residual so far."""
    k_n = len(p)
    frames = np.asarray(frames)
    ref = area[k:k + 4]
    lo_a, hi_a = ref.min(), ref.max()

    def usable(j: int, nxt: int) -> bool:  # frame j joins the fit next to frame nxt
        return (bool(p[j]) and hi_a <= AREA_JUMP * area[j] and area[j] <= AREA_JUMP * lo_a
                and (frames[j] - frames[nxt]) * (j - nxt) > 0)

    lo, hi = k, k + 3
    while lo > max(0, k - CONTACT_FIT_BEFORE) and usable(lo - 1, lo):
        lo -= 1
    while hi < min(k_n - 1, k + CONTACT_FIT_AFTER) and usable(hi + 1, hi):
        hi += 1
    best = None
    t = (frames[lo:hi + 1] - frames[lo]) / fps  # the clock's origin does not move the answer
    for i in (k + 2, k + 1, k):
        at, cost = kink_time(t, c[lo:hi + 1], i - lo + 1)
        if best is None or cost < EARLIER_RESIDUAL * best[2]:
            best = (i, at, cost)
    i, at = best[:2]
    return _pairs_time(tau, t[i - lo:i - lo + 2], i, at)


def contact_times(c, p, area, frames, fps, tau, contact_px) -> list[float | None]:
    """Per body: the time of its first abrupt change of motion (see the module docstring)."""
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
    return [None if k is None else _contact_time(c[:, b], p[:, b], area[:, b], frames, fps, tau, k)
            for b, k in enumerate(_first(fire))]


def rest_times(c, p, frames, fps, tau, rest_speed: float) -> list[float | None]:
    """Per body that moved and is seen in the last frame: the time its speed falls below
    ``rest_speed`` for good (linear between the middles of the last moving interval and of
    the first interval of the still run that lasts to the end of the clip)."""
    k_n, n_b = p.shape
    out: list[float | None] = [None] * n_b
    if k_n < 2:
        return out
    v, vok = _velocities(c, p, frames, fps)
    speed = np.linalg.norm(np.nan_to_num(v), axis=-1)
    mid = (tau[1:] + tau[:-1]) / 2
    for b in range(n_b):
        idx = np.flatnonzero(vok[:, b])
        if not p[-1, b] or len(idx) == 0:
            continue
        moving = idx[speed[idx, b] >= rest_speed]
        if len(moving) == 0 or speed[moving, b].max() < MOVED_FACTOR * rest_speed:
            continue
        after = idx[idx > moving[-1]]
        if len(after):  # else still moving at the end
            m, a = moving[-1], after[0]
            fast, slow = speed[m, b], speed[a, b]
            f = (fast - rest_speed) / (fast - slow)
            out[b] = float(mid[m] + f * (mid[a] - mid[m]))
    return out


def _exit_time(c, p, area, own, last: int, size) -> float | None:
    """When a body last seen (present) in frame ``last`` has wholly left the frame, on its
    clip's own clock: its centre's path (constant acceleration through its last ≤ 3 whole
    frames, area ≥ `EXIT_WHOLE_FRACTION` of its largest; else its last ≤ 3 frames) reaching an
    equivalent radius beyond an edge. None when the path does not."""
    h, w = size
    run = [last]
    while run[-1] > 0 and p[run[-1] - 1] and own[run[-1] - 1] < own[run[-1]]:
        run.append(run[-1] - 1)
    run = run[::-1]
    biggest = float(area[run].max())
    whole = [j for j in run if area[j] >= EXIT_WHOLE_FRACTION * biggest][-3:]
    pts = whole if len(whole) >= 2 else run[-3:]
    if len(pts) < 2:
        return None
    t0 = own[pts[-1]]
    radius = math.sqrt(biggest / math.pi)
    ts = own[pts] - t0
    best = None
    for axis, (low, high) in ((0, (-radius, w + radius)), (1, (-radius, h + radius))):
        coef = np.polyfit(ts, c[pts, axis], min(2, len(pts) - 1))
        for bound in (low, high):
            shifted = coef.copy()
            shifted[-1] -= bound
            for root in np.roots(shifted):
                if abs(root.imag) < 1e-9 and root.real >= -1e-9:
                    best = root.real if best is None else min(best, root.real)
    return None if best is None else float(best + t0)


def exit_times(c, p, area, max_area, tau, size, frames=None, fps: float = 1.0
               ) -> list[float | None]:
    """Per body: the time it wholly left the frame (see the module docstring) — in the
    interval after the last frame it is seen in (present), when it then stays missing and was
    last seen at the border. ``frames``/``fps``: the clip's own clock (default: ``tau``)."""
    k_n, n_b = p.shape
    out: list[float | None] = [None] * n_b
    h, w = size
    own = np.asarray(tau, float) if frames is None else np.asarray(frames, float) / fps
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
            t = _exit_time(c[:, b], p[:, b], area[:, b], own, last, size)
            out[b] = float(tau[last + 1]) if t is None else \
                _pairs_time(tau, own[last:last + 2], last, t)
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
            "exit": exit_times(c, p, a, d["st"]["max_area"], tau, size, f, fps)}


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
    miss, duration = MISSING_DIAG_FRACTION * d["diag"], d["duration"]
    ref, gen = d["ref"], d["gen"]
    pr, pg = ref["p"], gen["p"]

    either = pr | pg
    dist = np.where(pr & pg, np.linalg.norm(np.nan_to_num(ref["c"] - gen["c"]), axis=-1), miss)
    out["track_pos_err"] = float(dist[either].mean()) if either.any() else 0.0

    if d["n"] >= 2:
        vr, okr = _velocities(ref["c"], pr, ref["frames"], d["fps"])
        vg, okg = _velocities(gen["c"], pg, gen["frames"], d["fps"])
        pen = miss / duration
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
    version = "2"  # colour-tolerant association, bounded missing penalty
    score_range = (0.0, float("inf"))

    details_key = "tracks"

    def details(self, inp: MetricInput) -> dict:
        """Which dynamic bodies were tracked, and which were skipped and why; when this scene's
        clips were segmented here (not a cached score), per tracked body the generated frames
        found by the palette, by the colour-tolerant association, or not at all, and the
        median colour cost of the associated blobs."""
        palette = scene_palette(inp.scene)
        if palette is None:
            return {"tracked": [], "skipped": {},
                    "note": "no ground-truth spec or detection: nothing to track"}
        out: dict = {"tracked": list(palette.ids), "skipped": dict(palette.skipped)}
        memo = inp.extra.get("tracks")
        st = memo.get("value") if memo and memo.get("key") == (
            id(inp.reference), id(inp.generated)) else None
        if st is not None:
            src, cost = st["gen_source"], st["gen_colour_cost"]
            out["generated_frames"] = {
                bid: {"palette": int((src[:, b] == 1).sum()),
                      "association": int((src[:, b] == 2).sum()),
                      "not_found": int((src[:, b] == 0).sum()),
                      "colour_cost_median": (round(float(np.nanmedian(cost[:, b])), 3)
                                             if np.isfinite(cost[:, b]).any() else None)}
                for b, bid in enumerate(st["tracked"])}
        return out

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
    version = "3"  # sub-frame event times; colour-tolerant association


class EventRestErr(_TrackMetric):
    """Mean |Δt| of the time each body comes to rest for good (s)."""
    name = "event_rest_err"
    version = "3"  # sub-frame event times; colour-tolerant association


class EventExitErr(_TrackMetric):
    """Mean |Δt| of the time each body leaves the frame (s)."""
    name = "event_exit_err"
    version = "3"  # sub-frame event times; colour-tolerant association


METRICS = (TrackPosErr, TrackVelErr, EventContactErr, EventRestErr, EventExitErr)


@hookimpl
def visphy_register_metrics(register):
    for cls in METRICS:
        register(cls())
