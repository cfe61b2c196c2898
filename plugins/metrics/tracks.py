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

from __future__ import annotations

import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import LOWER, SEQUENCE, Metric, MetricInput
from visphy_plugins.metrics.track_kinematics import (  # noqa: F401 - re-exported
    _clip_consts,
    _event_error,
    _velocities,
    contact_times,
    exit_times,
    kink_time,
    rest_times,
)
from visphy_plugins.metrics.track_palette import Palette, classify, scene_palette  # noqa: F401
from visphy_plugins.metrics.track_segments import (  # noqa: F401 - re-exported
    MIN_SAMPLES,
    PRESENT_FRACTION,
    Tracks,
    generated_tracks,
    grid_stride,
    other_rows,
    palette_labels,
    scene_tracks,
    segment,
)

CONTACT_PX_MIN, CONTACT_DIAG_FRACTION = 4.0, 0.006  # change of motion that counts as contact
REST_PX_PER_FRAME = 1.0         # below this speed (px per frame of the clip) a body is still
MISSING_DIAG_FRACTION = 0.25    # a body seen in one clip only: a quarter of the diagonal

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
