"""Object-level metrics ("Validity II", docs/metrics.md): where things move and where each body is,
measured so that *how* a body is drawn — 10% larger or smaller, paler, darker, hue-turned, its
colours swapped among the bodies, outlined, anti-aliased, H.264-encoded — barely matters, while
*where it goes* does. New columns next to the metrics they re-measure, whose values (and the
``paper`` protocol's) are unchanged; which of them enter the headline is the validity study's
to decide (`visphy_core.scoring.headline`).

Why. The validity study (``plugins/studies/validity/``) finds the headline's
components moving with the drawing: Physics-IQ's motion masks (`motion_masks`) are compared pixel
for pixel, and a moving body's mask is the band its outline sweeps, so a body drawn 10% larger
costs the IoUs about as much as a path 15–20 px off; `track_pos_err` follows colour, so a
palette swapped among the bodies sends it to its worst value.

The typical body
----------------
The scene's tracked bodies (`tracks.scene_palette`: each dynamic body of a colour of its own,
from the spec, else the detection), segmented in the *reference* by their exact palette as
`tracks` does (its memo is reused when the track metrics ran): per body b its equivalent radius
r_b = √(A_b / π), A_b its largest visible area (px of the full frame; at least `MIN_RADIUS_PX`,
4 px). The typical moving body's radius is r̄ = Σ_b w_b r_b / Σ_b w_b with w_b = r_b · L_b, L_b the
length of b's centroid path in the reference: the radius averaged over the bands the bodies
sweep in the motion masks (a band's area grows with its body's width times its path). When no
body moves: the median radius; without a palette: `FALLBACK_RADIUS_FRACTION` (4%) of the frame's
longer side (20 px at 512²; PHYRE's balls are 15–35 px). Everything here depends on the reference
alone, so every clip of a scene — the still clip (the headline's floor) and the twin (its
ceiling) included — is measured with one yardstick.

``spatiotemporal_iou_tol``, ``weighted_spatial_iou_tol`` ↑ (family ``motion_mask``)
------------------------------------------------------------------------------------
*Masks*: `motion_masks`' (working resolution 256 px, 3×3 blur, 0.2 s span, 5×5 closing) with one
change: a pixel moves when its blurred luma changes by more than 10 (as there) **or** any of its
blurred RGB channels by more than `COLOUR_THRESHOLD` (20). Luma alone misses a body moving over a
surface of its own lightness — a pale or tinted body over the 3D floor: on 3D test scenes the
tolerant spatiotemporal IoU of the 40%-paler clip rises from 0.856 to 0.967 (t004-v01), the
20°-tinted one from 0.947 to 0.991 (t008-v01), the swapped palette from 0.897 to 0.965
(t010-v01); on the 2D scenes below nothing changes. 20 lies above every static pixel's change in
the H.264 encodings (crf 23, as published) of 8 2D and 3 3D test scenes (largest 16 in 2D, 7 in
3D, over 8.2 M and 13.9 M pixel-frames; at crf 35, 11 of the 3D's 13.9 M exceed it, none in 2D).
CIELAB ΔE > 12 separates as well (largest static ΔE 7.6) at 30 times the cost (a 3 ms Lab
conversion per frame).

*Tolerance*: ρ = max(`RHO_FLOOR_PX`, `RHO_FRACTION` · r̄ · s) working px, s the working scale (½
at 512²): 15% of the typical radius, at least one working pixel (the masks' edges are quantised
to it). A body drawn 10% larger moves its edge by a tenth of its radius, inside ρ; a path 20 px
off (10 working px) lies far outside. On 14 2D test scenes (luma masks), ρ at 10, 15, 20, 25% of
r̄ left the ±10% clips a median normalised cost of 0.056, 0.002, 0.001, 0.000 (spatiotemporal)
while the share of ≥ 20-px physics errors costing ≥ 0.2 went 0.88, 0.87, 0.83, 0.78
(spatiotemporal) and 0.57, 0.47, 0.36, 0.29 (weighted). With R_i, G_i the paired masks
(reference, generated) and R_i^ρ, G_i^ρ the pixels within Euclidean distance ρ of them (a
dilation by the disc of radius ρ):

    T = ½ Σ_i (Σ_{p∈R_i} κ(d_G(p)) + Σ_{p∈G_i} κ(d_R(p)))   moving pixels the other clip
                                                            explains, both ways
    spatiotemporal_iou_tol   = T / (Σ_i |R_i| + Σ_i |G_i| − T)
    M = ½ Σ_p (min(c_R(p), c_G^ρ(p)) + min(c_G(p), c_R^ρ(p)))
    weighted_spatial_iou_tol = M / (Σ_p c_R(p) + Σ_p c_G(p) − M)

d_G(p): the distance from p to the nearest moving pixel of G_i in its frame (`distances`);
κ(d) = 1 for d ≤ ρ, falling linearly to 0 at ρ + λ (`closeness`), λ = `RAMP_FRACTION` · r̄ · s
(15 % of the typical radius more: version 2 of ``spatiotemporal_iou_tol``; version 1 was the
hard edge, λ = 0). c(p): the number of paired frames in which p moves; c^ρ(p): in which p lies
within ρ of a moving pixel (the weighted IoU keeps the hard edge). At ρ = λ = 0 they are exactly
the plain ``spatiotemporal_iou`` and ``weighted_spatial_iou`` (T = Σ|R_i ∩ G_i|, and
Σ min + Σ max = Σ c_R + Σ c_G) of these masks.

Why the ramp: with a hard edge every path more than ρ off costs the same, so once a clip's
bodies no longer overlap their true places the IoU stops falling as the error grows — two
restitution doses 25 and 59 px off scored 0.713 and 0.739 (`2d-t015-v00`), 72 and 141 px off
0.649 and 0.671 (`2d-t065-v00`). With the ramp the near misses still count a little and the
far ones nothing, so the IoU falls with the distance over the first fraction of a radius: on the
validity study's checkpoint of the test split (49 scenes, 157 dose series) λ = 0.1, 0.15, 0.25,
0.35, 0.5 of r̄ made 144–146 series monotone (the hard edge 141), while the 4-px outline moved
the headline by a median 0.020 or less; λ above 0.25 r̄ let the flow extrapolation climb
above more physics-wrong clips (docs/metrics.md, Validity II). Identical clips score 1, a
still clip 0 (it has no moving pixel), and they are NaN where the reference never moves.

``track_pos_err_rel`` ↓ (family ``physics``, body radii, in [0, K])
-------------------------------------------------------------------
*Reference*: the tracked bodies' centroids and presence, as `tracks` finds them.

*Generated clip, colour-blind*: its blobs (`association.find_blobs`: foreground away from the
background colours, regions of smoothly varying colour, a blob's core and the samples touching
it; the very blobs the track metrics cut, reused when they ran) grouped by *drawn colour*: blobs
whose tint-tolerant colour cost (`association.colour_cost`, with L* differences at
`GROUP_LIGHTNESS_SIGMA` (80) instead of 40, so the lit and the shaded faces of a 3D box are one
colour while black, grey and white are not) is at most `GROUP_COST` (0.45, half the closest pair
of the benchmark's palette: blue–purple at 0.9) are linked, transitively. Blobs of one group
that touch in one frame are one *object* (a body cut by an occluder, the faces of a box).

*Which colour draws which body*: one assignment for the whole clip
(`scipy.optimize.linear_sum_assignment`), by where things are, not by colour. The cost of
explaining body b by group g is the mean, over the pairs where b is present in the reference or
g shows an object, of e(d) to g's nearest object (both seen) or K (one of them only), plus two
tie-breakers: `COLOUR_PRIOR` (0.1) × the colour cost between b's palette colour and g's mean
colour, and `SIZE_PRIOR` (0.1) × (|ln(g's median object area / A_b)| / ln 2, capped at
`SIZE_CAP` 1.5)². A group explains as many bodies as it shows objects in at least half of the
pairs where it shows any (bodies drawn in one colour), not counting slivers, objects under
`PIECE_FRACTION` (¼) of the group's largest in that pair (a body an occluder splits stays one);
a body may be explained by none: missing, K wherever the reference shows it, chosen only when
every group costs more than K + `COLOUR_PRIOR` × `association.COLOUR_GATE` (a body drawn far
off in its own colour is found, not missing). A palette swapped among the bodies, or any
recolouring, is thus matched by the paths; a group's colour and size only break ties (a
colour weight of 0.25 already mismatched one swapped scene of the 24 below).

*Per pair*, the bodies a group explains take its objects, nearest first, one each; a body
present in the reference and not taken is missing, an object taken by a body the reference
does not show there counts as seen in the generated clip only.

*Error*: e(d) = K · tanh(max(0, d / r_b − δ) / K) radii, K = `CAP_RADII` (1.5), δ =
`TOLERANCE_RADII` (0.15); a body seen in one clip only costs K. ``track_pos_err_rel`` is the mean
of e over the pairs and tracked bodies seen in either clip; NaN when no tracked body is present
in the paired reference frames. In radii, so an error means the same for a 15-px ball and a
60-px box, at any resolution. δ: a body drawn 10% larger or smaller about an off-centre origin
(a jar scaled about its base), or outlined where the frame cuts it, moves its *visible* centroid
by up to ~0.18 of its radius (H.264 by ≤ 0.35 px); measured on the 24 scenes below, δ = 0, 0.1,
0.15 leave the worst ±10% clip at a normalised 0.089, 0.024, 0 and lower the share of ≥ 20-px
physics errors that cost ≥ 0.2 from 0.68 to 0.63 and 0.61. K: the soft cap keeps one lost body
from weighing more than one K radii off (the pixel error's miss costs a quarter of the
diagonal); on 20 of those scenes (δ = 0) K = 1, 1.5, 2, 3 gave that share as 0.74, 0.68, 0.58,
0.51 (strictly monotone dose series 0.48, 0.51, 0.51, 0.51), and with K = 2 and 3, 2 and 5 of
the 183 physics-wrong clips scored below the still clip (none with K ≤ 1.5). A path a constant
~1 radius off from the first frame scores about what a still clip does: the cap rates both
"elsewhere".

Measured with version 1 (the hard edge; the ramp's effect: *Why the ramp* above) (a harness
outside the suite: the first 24 2D scenes of the test split, exact clips,
unaligned pairing; normalised as the headline does, floor = the still clip, ceiling = the twin,
clipped to [−1, 1]). Restyles (the validity study's ``restyles.APPEARANCES`` and an H.264
crf-23 encoding): median over scenes of the drop from the truth's normalised value (the goal:
≤ 0.05):

    restyle          st_iou  st_iou_tol  ws_iou  ws_iou_tol  track_pos_err  track_pos_err_rel
    grow +10%         0.196     0.003     0.196     0.005        0.000          0.000
    shrink −10%       0.211     0.002     0.214     0.003        0.000          0.000
    outline 2 px      0.022     0.000     0.039     0.000        0.000          0.000
    outline 4 px      0.077     0.008     0.095     0.009        0.000          0.000
    swapped palette   0.000     0.000     0.000     0.000        1.770          0.000
    pale, dark, tint ±20°, outline 1 px, anti-aliased, thick bars, background 15% darker,
    H.264: ≤ 0.010 for every column (0.000 for the new ones).

(90th percentile over scenes: grow 0.287 → 0.020 (st), swapped 2.0 → 0.0 (track).) Physics
errors that move a body ≥ 20 px (gravity ×0.9/0.75/0.5, restitution −0.1/−0.2/−0.3, launch angle
+5/10/20°, playback speed ×0.9/0.8/0.67, and every moving body drawn 20 px off its path): share
of the 203 clips whose normalised value drops by ≥ 0.2 — st_iou 0.91, st_iou_tol 0.87, ws_iou
0.73, ws_iou_tol 0.47, track_pos_err 0.14, track_pos_err_rel 0.61; share of the 75 dose series
strictly decreasing — 0.65, 0.61, 0.23, 0.29, 0.57, 0.55 (restitution −0.2 and −0.3 clamp alike
at 0 from PHYRE's 0.2). Median drops: gravity ×0.75 0.61, 0.48, 0.27, 0.20, 0.06, 0.24; the 20-px
offset 0.60, 0.47, 0.42, 0.30, 0.08, 0.33. 3D (test scenes t004-v01, t008-v01, t010-v01,
75 frames, three.js; pale, dark, tint ±20°, multisampling off, ±10%, swapped, background 15%
darker): the largest drop any restyle causes on a scene is 0.141, 0.031, 0.255, 0.121, 1.223,
0.122 (the new columns' worst: the swapped palette of t008 for the weighted IoU, the 40%-darker
bodies of t008 for the track error); gravity ×0.5 and the 20-px offset drop the new columns by a
median 0.89/0.62 (st), 0.15/0.41 (ws), 0.59/0.78 (track) (t004-v01 is chaotic: its twin is far
from the truth, and its normalised values clip).

Limits. Blobs are cut on a grid of every 2nd pixel at 512²: a part thinner than about three grid
steps has no core and is not seen, so a 10-px jar wall or bar with a 4-px outline on both sides
leaves the body missing (the outline-4-px restyle: median 0, 90th percentile 0.31 normalised;
`track_pos_err`: 0.62). Two bodies drawn in one colour and touching are one object. Within a
group, objects go to the nearest bodies, so a body drawn in another body's colour right where
that body should be is taken for it. A pale 3D face within ΔE 6 of the sky, or a dark one
near the floor's colour, is background (`association.FG_DE`): the body's visible centroid moves
(t010's 40%-paler grey box: ~0.3 radii; t008's darker bodies: 0.08 radii on average).

Cost (one core, the median over 2D test scenes, 512², 17 frames): both IoUs 45–50 ms on their
own (the working frames, the luma masks and the reference's segmentation included), 15 ms when
`motion_masks` and `tracks` ran on the scene (the default suite); ``track_pos_err_rel`` 90–110
ms on its own (mostly the generated clip's blobs), 4 ms after the track metrics. 3D (512², 75
frames), after the metrics they share with: 65–95 ms and 15–45 ms. Each clip's masks,
neighbourhoods and objects are made once per scene (`MetricInput.extra`), each pairing's values
once.
"""
# size: one family: the tolerant masks and the palette-free tracks share the bodies' sizes and blobs

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import HIGHER, LOWER, SEQUENCE, Metric, MetricInput
from visphy_plugins.metrics import motion_masks as MM
from visphy_plugins.metrics import tracks as TR
from visphy_plugins.metrics.association import (
    COLOUR_GATE,
    colour_cost,
    colour_features,
    dominant_colours,
    find_blobs,
)

_MEMO_KEY = "object_level"

RHO_FRACTION = 0.15         # mask tolerance ρ: this fraction of the typical moving body's radius
RHO_FLOOR_PX = 1.0          # ...and at least one working pixel
RAMP_FRACTION = 0.15        # beyond ρ a match counts less, down to nothing at ρ + this · radius
FALLBACK_RADIUS_FRACTION = 0.04  # no palette: a body radius of 4% of the longer side
COLOUR_THRESHOLD = 20       # masks: a blurred RGB channel changing by more than this moves too
CAP_RADII = 1.5             # K: a body's error in a pair is K·tanh(d / (K·r)) radii...
TOLERANCE_RADII = 0.15      # ...less this much of its radius (δ: a drawing's centroid shift)
MIN_RADIUS_PX = 4.0         # r is at least this (px of the full frame)
GROUP_COST = 0.45           # blobs whose colours are this close are one drawn colour...
GROUP_LIGHTNESS_SIGMA = 80.0  # ...with L* differences counting half as much as the tracker's
COLOUR_PRIOR = 0.1          # the whole-clip choice: weight of the colour cost (a tie-breaker)
SIZE_PRIOR = 0.1            # ...and of the squared size mismatch (|ln area ratio| / ln 2)
SIZE_CAP = 1.5              # ...capped at 1.5 (a third or thrice the area)
PIECE_FRACTION = 0.25       # an object under this share of its group's largest: a sliver


# ----------------------------------------------------------------------------- body sizes
@dataclass
class RefBodies:
    """The reference's tracked bodies: the scene's palette, centroids (N×B×2, px of the full
    frame), presence (N×B) and equivalent radii (B, px)."""

    palette: TR.Palette
    centroid: np.ndarray
    present: np.ndarray
    radius: np.ndarray


def reference_bodies(inp: MetricInput) -> RefBodies | None:
    """The reference's tracked bodies, segmented by the scene's palette as `tracks` does
    (reused from the track metrics' memo when they ran on this clip); None without a palette
    (no spec, no detection)."""
    memo = inp.extra.setdefault(_MEMO_KEY, {})
    key = ("ref", id(inp.reference))
    if key in memo:
        return memo[key]
    palette = TR.scene_palette(inp.scene)
    out = None
    if palette is not None:
        shared = inp.extra.get("tracks") or {}
        st = shared.get("value") if (shared.get("key") or (None,))[0] == id(inp.reference) \
            else None
        if st is not None:
            ref, present = st["ref"], st["ref_present"]
        else:
            ref = TR.segment(inp.reference, palette)
            floor = TR.MIN_SAMPLES * ref.stride ** 2
            max_area = ref.area.max(axis=0, initial=0.0)
            present = (ref.area >= np.maximum(floor, TR.PRESENT_FRACTION * max_area)) \
                & (ref.core >= floor)
        radius = np.maximum(np.sqrt(ref.area.max(axis=0, initial=0.0) / math.pi),
                            MIN_RADIUS_PX)
        out = RefBodies(palette, ref.centroid, present, radius)
    memo[key] = out
    return out


def typical_radius(inp: MetricInput) -> tuple[float, str]:
    """The typical moving body's equivalent radius (px of the full frame) and where it came
    from (module docstring)."""
    bodies = reference_bodies(inp)
    if bodies is None or bodies.radius.size == 0 or not bodies.present.any():
        return FALLBACK_RADIUS_FRACTION * max(np.shape(inp.reference)[1:3]), "fallback"
    c, p = bodies.centroid, bodies.present
    step = np.linalg.norm(np.nan_to_num(c[1:] - c[:-1]), axis=-1)
    path = np.where(p[1:] & p[:-1], step, 0.0).sum(axis=0)
    weight = bodies.radius * path
    if weight.sum() > 0:
        return float((weight * bodies.radius).sum() / weight.sum()), "moving bodies"
    return float(np.median(bodies.radius[p.any(axis=0)])), "bodies (none moves)"


# ----------------------------------------------------------------------------- masks
def colour_motion_masks(small: np.ndarray, fps: float, params: MM.MaskParams = MM.DEFAULT_PARAMS
                        ) -> np.ndarray:
    """N×h×w bool motion masks of a clip at its working resolution (``small``, N×h×w×3
    uint8): `motion_masks.motion_masks`' blurred-luma change over the span, or a change of
    more than `COLOUR_THRESHOLD` in any blurred RGB channel; then the same closing."""
    n = len(small)
    masks = np.zeros(small.shape[:3], dtype=bool)
    if n < 2:
        return masks
    k = params.blur_px
    blurred = [cv2.GaussianBlur(f, (k, k), 0) if k > 1 else f for f in small]
    luma = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in blurred]  # BT.601
    w = params.step(fps)
    kernel = np.ones((params.close_px, params.close_px), np.uint8)
    within = (COLOUR_THRESHOLD,) * 3
    for t in range(1, n):
        s = max(0, t - w)
        still = cv2.inRange(cv2.absdiff(blurred[t], blurred[s]), (0, 0, 0), within)  # 255: all
        moving = (cv2.absdiff(luma[t], luma[s]) > params.threshold) | (still == 0)
        moving = moving.view(np.uint8)
        if params.close_px > 1:
            moving = cv2.morphologyEx(moving, cv2.MORPH_CLOSE, kernel)
        masks[t] = moving > 0
    return masks


def clip_masks(inp: MetricInput, role: str) -> np.ndarray:
    """A clip's colour motion masks (``role``: ``ref`` or ``gen``), once per scene, from the
    working frames `motion_masks` makes (shared with its metrics)."""
    memo = inp.extra.setdefault(_MEMO_KEY, {})
    key = ("masks", role)
    if key not in memo:
        memo[key] = colour_motion_masks(MM.clip_masks(inp, role).small, MM._fps(inp))
    return memo[key]


def tolerance(inp: MetricInput) -> dict:
    """The scene's mask tolerance: ``rho_px`` and ``ramp_px`` (working px), the typical radius
    they come from
    (``radius_px``, px of the full frame, and ``radius_from``) and the working ``scale``."""
    memo = inp.extra.setdefault(_MEMO_KEY, {})
    if "rho" not in memo:
        radius, source = typical_radius(inp)
        h, w = np.shape(inp.reference)[1:3]
        scale = max(MM.DEFAULT_PARAMS.working_shape(h, w)) / max(h, w)
        memo["rho"] = {"rho_px": max(RHO_FLOOR_PX, RHO_FRACTION * radius * scale),
                       "ramp_px": RAMP_FRACTION * radius * scale,
                       "radius_px": radius, "radius_from": source, "scale": scale}
    return memo["rho"]


def distances(masks: np.ndarray) -> np.ndarray:
    """Per frame, each pixel's Euclidean distance to the frame's mask (K×h×w float32; inf in
    a frame without a moving pixel). Exact: OpenCV's precise transform can differ in the last
    bit with the buffer's alignment, so each squared distance (an integer) is rounded and the
    root taken again — the same frames give the same distances, run after run."""
    out = np.full(masks.shape, np.inf, dtype=np.float32)
    for i, m in enumerate(masks):
        if m.any():
            d = cv2.distanceTransform((~m).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            out[i] = np.sqrt(np.rint(d * d))
    return out


def closeness(dist: np.ndarray, rho: float, ramp: float = 0.0) -> np.ndarray:
    """How much a pixel at distance ``dist`` from the other clip's mask counts as explained: 1
    within ``rho`` (exactly the disc dilation's ``≤ ρ``), falling linearly to 0 at
    ``rho + ramp`` (``ramp`` 0: a hard edge)."""
    if ramp > 0:
        return np.clip(1.0 - (dist - rho) / ramp, 0.0, 1.0)
    return (dist <= rho).astype(np.float32)


def tolerant_ious(ref: np.ndarray, gen: np.ndarray, ref_dist: np.ndarray, gen_dist: np.ndarray,
                  rho: float, ramp: float = 0.0) -> tuple[float, float]:
    """(spatiotemporal, weighted spatial) tolerant IoU of K paired masks (K×h×w bool), from
    each one's `distances` (module docstring): the spatiotemporal one with the ramp, the
    weighted one with the hard edge at ``rho``; NaN when ``ref`` never moves."""
    n_r, n_g = int(np.count_nonzero(ref)), int(np.count_nonzero(gen))
    if n_r == 0:
        return float("nan"), float("nan")
    t = (float(closeness(gen_dist[ref], rho, ramp).sum(dtype=np.float64))
         + float(closeness(ref_dist[gen], rho, ramp).sum(dtype=np.float64))) / 2.0
    cr, cg = np.count_nonzero(ref, axis=0), np.count_nonzero(gen, axis=0)
    nr, ng = np.count_nonzero(ref_dist <= rho, axis=0), np.count_nonzero(gen_dist <= rho, axis=0)
    m = (np.minimum(cr, ng).sum() + np.minimum(cg, nr).sum()) / 2.0
    return float(t / (n_r + n_g - t)), float(m / (n_r + n_g - m))


MASK_NAMES = ("spatiotemporal_iou_tol", "weighted_spatial_iou_tol")


def mask_values(inp: MetricInput, alignment) -> dict[str, float]:
    """The two tolerant IoUs under ``alignment`` (memoised per pairing and scene)."""
    ri = np.asarray(alignment.ref_idx, dtype=int)
    gi = np.asarray(alignment.gen_idx, dtype=int)
    memo = inp.extra.setdefault(_MEMO_KEY, {})
    key = ("mask_values", ri.tobytes(), gi.tobytes())
    if key in memo:
        return memo[key]
    if len(ri) == 0:
        out = dict.fromkeys(MASK_NAMES, float("nan"))
    else:
        tol = tolerance(inp)
        masks, dist = {}, {}
        for role in ("ref", "gen"):
            masks[role] = clip_masks(inp, role)
            if ("dist", role) not in memo:  # each clip's once per scene (pairings share frames)
                memo[("dist", role)] = distances(masks[role])
            dist[role] = memo[("dist", role)]
        st, ws = tolerant_ious(masks["ref"][ri], masks["gen"][gi], dist["ref"][ri],
                               dist["gen"][gi], tol["rho_px"], tol["ramp_px"])
        out = {"spatiotemporal_iou_tol": st, "weighted_spatial_iou_tol": ws}
    memo[key] = out
    return out


# ----------------------------------------------------------------------------- tracks
def soft_error(d, r):
    """A distance ``d`` (px) for a body of radius ``r`` in radii: K·tanh(max(0, d/r − δ) / K)
    (K = `CAP_RADII`, δ = `TOLERANCE_RADII`)."""
    x = np.maximum(np.asarray(d, float) / np.asarray(r, float) - TOLERANCE_RADII, 0.0)
    return CAP_RADII * np.tanh(x / CAP_RADII)


@dataclass
class GenObjects:
    """The generated clip's objects (blobs of one drawn colour touching in one frame, joined):
    per object its ``frame``, ``area`` (px), ``centroid`` ((x, y) px) and colour ``group``;
    per group its mean colour (``group_rgb``, area-weighted) and median object area."""

    frame: np.ndarray
    area: np.ndarray
    centroid: np.ndarray
    group: np.ndarray
    group_rgb: np.ndarray
    group_area: np.ndarray

    @property
    def n_groups(self) -> int:
        return len(self.group_rgb)


def generated_objects(inp: MetricInput, palette: TR.Palette) -> GenObjects:
    """The generated clip's objects (module docstring), once per clip and scene."""
    return clip_objects(inp, inp.generated, palette.background)


def clip_objects(inp: MetricInput, clip: np.ndarray, background: tuple = ()) -> GenObjects:
    """A clip's objects (blobs of one drawn colour touching in one frame, joined; module
    docstring), once per clip and scene: its blobs are cut away from ``background`` (the
    scene palette's background colours) and the clip's own dominant colours."""
    memo = inp.extra.setdefault(_MEMO_KEY, {})
    key = ("gen_objects", id(clip))
    if key in memo:
        return memo[key]
    frames = np.asarray(clip)
    kept = inp.extra.get("tracks.blobs") or {}
    if kept.get("key") == id(clip):  # the track metrics' blobs of this clip
        blobs = kept["blobs"]
    else:
        s = TR.grid_stride(*frames.shape[1:3])
        blobs = find_blobs(frames, tuple(background) + tuple(dominant_colours(frames, s)), s,
                           TR.MIN_SAMPLES)
    m = len(blobs)
    if m == 0:
        out = GenObjects(np.zeros(0, int), np.zeros(0), np.zeros((0, 2)), np.zeros(0, int),
                         np.zeros((0, 3)), np.zeros(0))
    else:
        feats = colour_features(blobs.rgb)
        close = colour_cost(feats, feats, GROUP_LIGHTNESS_SIGMA) <= GROUP_COST
        n_g, group = connected_components(coo_matrix(close), directed=False)
        t = blobs.touching.reshape(-1, 2)
        same = (group[t[:, 0]] == group[t[:, 1]]) & (blobs.frame[t[:, 0]] == blobs.frame[t[:, 1]])
        graph = coo_matrix((np.ones(int(same.sum())), (t[same, 0], t[same, 1])), shape=(m, m))
        n_o, obj = connected_components(graph, directed=False)
        area = np.bincount(obj, weights=blobs.area, minlength=n_o)
        centroid = np.stack([np.bincount(obj, weights=blobs.area * blobs.centroid[:, j],
                                         minlength=n_o) / area for j in range(2)], axis=1)
        frame, ogroup = np.zeros(n_o, int), np.zeros(n_o, int)
        frame[obj], ogroup[obj] = blobs.frame, group
        weight = np.bincount(group, weights=blobs.area, minlength=n_g)
        rgb = np.stack([np.bincount(group, weights=blobs.area * blobs.rgb[:, j], minlength=n_g)
                        for j in range(3)], axis=1) / weight[:, None]
        out = GenObjects(frame, area, centroid, ogroup, rgb,
                         np.array([np.median(area[ogroup == g]) for g in range(n_g)]))
    memo[key] = out
    return out


def _capacity(count: np.ndarray) -> int:
    """How many bodies a group can explain: the median of its object count (slivers aside)
    over the pairs where it shows any (rounded down: it shows that many in at least half of
    them)."""
    shown = count[count > 0]
    return int(np.median(shown)) if len(shown) else 0


def relative_track_error(inp: MetricInput, alignment) -> tuple[float, dict]:
    """``track_pos_err_rel`` under a pairing, and how the bodies were matched (module
    docstring): NaN when no tracked body is present in the paired reference frames."""
    bodies = reference_bodies(inp)
    ri = np.asarray(alignment.ref_idx, dtype=int)
    gi = np.asarray(alignment.gen_idx, dtype=int)
    if bodies is None or len(ri) == 0 or not bodies.present[ri].any():
        return float("nan"), {}
    c_ref, p_ref, radius = bodies.centroid[ri], bodies.present[ri], bodies.radius
    k_n, n_b = p_ref.shape
    objs = generated_objects(inp, bodies.palette)
    n_g = objs.n_groups
    per = [np.flatnonzero(objs.frame == f) for f in gi.tolist()]  # objects of each pair
    count = np.zeros((k_n, n_g), int)   # objects of each group in each pair
    bodies_shown = np.zeros((k_n, n_g), int)  # ...not counting slivers (`PIECE_FRACTION`)
    for k, idx in enumerate(per):
        g_of = objs.group[idx]
        np.add.at(count[k], g_of, 1)
        largest = np.zeros(n_g)
        np.maximum.at(largest, g_of, objs.area[idx])
        np.add.at(bodies_shown[k], g_of[objs.area[idx] >= PIECE_FRACTION * largest[g_of]], 1)
    # the whole-clip cost of explaining body b by group g: the mean over the pairs where
    # either is seen of the soft error to g's nearest object, K where only one is seen
    total = np.zeros((n_b, n_g))
    n_seen = np.zeros((n_b, n_g))
    for k, idx in enumerate(per):
        nearest = np.full((n_g, n_b), np.inf)
        if len(idx):
            d = np.hypot(*(objs.centroid[idx][:, None, :] - c_ref[k][None, :, :]
                           ).transpose(2, 0, 1))                               # M×B
            np.minimum.at(nearest, objs.group[idx], soft_error(np.nan_to_num(d, nan=np.inf),
                                                               radius[None, :]))
        has_g = count[k] > 0
        both = p_ref[k][:, None] & has_g[None, :]
        total += np.where(both, nearest.T, np.where(p_ref[k][:, None] | has_g[None, :],
                                                    CAP_RADII, 0.0))
        n_seen += p_ref[k][:, None] | has_g[None, :]
    cost = np.divide(total, n_seen, out=np.zeros_like(total), where=n_seen > 0)
    colour = colour_cost(colour_features(np.array(bodies.palette.tracked, float)),
                         colour_features(objs.group_rgb)) if n_g else np.zeros((n_b, 0))
    size = np.minimum(np.abs(np.log(np.maximum(objs.group_area, 1.0)[None, :]
                                    / (math.pi * radius[:, None] ** 2))) / math.log(2.0),
                      SIZE_CAP) if n_g else np.zeros((n_b, 0))
    choice = cost + COLOUR_PRIOR * colour + SIZE_PRIOR * size ** 2
    # a group may explain as many bodies as it shows objects (slivers aside) in most of its
    # frames: a body an occluder splits is still one; a body may also be explained by nothing
    # (missing: K in every pair it is seen)
    slots = [(g, s) for g in range(n_g) for s in range(_capacity(bodies_shown[:, g]))]
    full = np.full((n_b, len(slots) + n_b), np.inf)
    for j, (g, s) in enumerate(slots):
        full[:, j] = choice[:, g] + 1e-9 * s
    # missing costs K and the prior of a colour at the association's gate: a body drawn far
    # off in its own colour is not called missing
    missing = CAP_RADII + COLOUR_PRIOR * COLOUR_GATE
    full[np.arange(n_b), len(slots) + np.arange(n_b)] = np.where(p_ref.any(axis=0), missing,
                                                                 0.0)
    rows, picks = linear_sum_assignment(full)
    mapping = {int(b): (slots[j][0] if j < len(slots) else -1) for b, j in zip(rows, picks)}
    # per pair, the bodies a group explains take its objects: the nearest ones, one each
    c_gen = np.full((k_n, n_b, 2), np.nan)
    p_gen = np.zeros((k_n, n_b), bool)
    for g in sorted(set(mapping.values()) - {-1}):
        members = [b for b, gg in mapping.items() if gg == g]
        for k, idx in enumerate(per):
            idx = idx[objs.group[idx] == g]
            want = [b for b in members if p_ref[k, b]]
            left = len(idx)
            if want and len(idx):
                d = np.hypot(*(objs.centroid[idx][None, :, :] - c_ref[k, want][:, None, :]
                               ).transpose(2, 0, 1))
                for r_, c_ in zip(*linear_sum_assignment(d)):
                    c_gen[k, want[r_]] = objs.centroid[idx[c_]]
                    p_gen[k, want[r_]] = True
                    left -= 1
            for b in [b for b in members if not p_ref[k, b]][:max(left, 0)]:
                p_gen[k, b] = True  # shown where the reference does not show it
    either = p_ref | p_gen
    d = np.linalg.norm(np.nan_to_num(c_ref - c_gen), axis=-1)
    err = np.where(p_ref & p_gen, soft_error(d, radius[None, :]), CAP_RADII)
    value = float(err[either].mean()) if either.any() else 0.0
    ids = bodies.palette.ids
    info = {"radius_px": {ids[b]: round(float(radius[b]), 2) for b in range(n_b)},
            "drawn_as": {ids[b]: (None if g < 0 else [int(round(v)) for v in objs.group_rgb[g]])
                         for b, g in sorted(mapping.items())},
            "error_radii": {ids[b]: (round(float(err[either[:, b], b].mean()), 4)
                                     if either[:, b].any() else None) for b in range(n_b)}}
    return value, info


def _unaligned_key(inp: MetricInput) -> tuple:
    n = min(len(inp.reference), len(inp.generated))
    idx = np.arange(n, dtype=int).tobytes()
    return idx, idx


# ----------------------------------------------------------------------------- metrics
class _TolerantIoU(Metric):
    """A tolerant motion-mask IoU (module docstring)."""

    kind = SEQUENCE
    needs = ("frames", "scene_spec")
    weights = None
    version = "1"
    family = "motion_mask"
    direction = HIGHER
    score_range = (0.0, 1.0)
    details_key = "motion_masks_tol"

    def identity(self) -> str:
        return (f"{super().identity()}/{MM.DEFAULT_PARAMS.key()}/rgb={COLOUR_THRESHOLD}"
                f"/rho={RHO_FRACTION}/floor={RHO_FLOOR_PX}")

    def compute_sequence(self, inp: MetricInput, alignment) -> float:
        return mask_values(inp, alignment)[self.name]

    def details(self, inp: MetricInput) -> dict:
        """The tolerance ρ and the typical body radius it comes from."""
        return {k: (round(v, 4) if isinstance(v, float) else v)
                for k, v in tolerance(inp).items()}


class SpatiotemporalIoUTol(_TolerantIoU):
    name = "spatiotemporal_iou_tol"
    version = "2"  # 2: the ramp beyond ρ (`RAMP_FRACTION`)

    def identity(self) -> str:
        return f"{super().identity()}/ramp={RAMP_FRACTION}"


class WeightedSpatialIoUTol(_TolerantIoU):
    name = "weighted_spatial_iou_tol"


class TrackPosErrRel(Metric):
    """The tracked bodies' position error in body radii, palette-free (module docstring)."""

    name = "track_pos_err_rel"
    kind = SEQUENCE
    needs = ("frames", "scene_spec")
    weights = None
    version = "1"
    family = "physics"
    direction = LOWER
    score_range = (0.0, CAP_RADII)
    details_key = "track_pos_err_rel"

    def identity(self) -> str:
        return f"{super().identity()}/K={CAP_RADII}/tol={TOLERANCE_RADII}"

    def compute_sequence(self, inp: MetricInput, alignment) -> float:
        return self._value(inp, np.asarray(alignment.ref_idx, dtype=int).tobytes(),
                           np.asarray(alignment.gen_idx, dtype=int).tobytes(), alignment)[0]

    @staticmethod
    def _value(inp: MetricInput, ri: bytes, gi: bytes, alignment) -> tuple[float, dict]:
        memo = inp.extra.setdefault(_MEMO_KEY, {})
        if ("rel", ri, gi) not in memo:
            memo[("rel", ri, gi)] = relative_track_error(inp, alignment)
        return memo[("rel", ri, gi)]

    def details(self, inp: MetricInput) -> dict | None:
        """Under the unaligned pairing, when it was computed here (not a cached score): each
        body's radius, the colour it was found drawn in (None: missing) and its error."""
        got = (inp.extra.get(_MEMO_KEY) or {}).get(("rel", *_unaligned_key(inp)))
        return got[1] if got else None


METRICS = (SpatiotemporalIoUTol, WeightedSpatialIoUTol, TrackPosErrRel)


@hookimpl
def visphy_register_metrics(register):
    for cls in METRICS:
        register(cls())
