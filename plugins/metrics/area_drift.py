"""``body_area_drift`` ↓ (family ``physics``, in [0, ln 4]): do the drawn bodies keep their size?

A rigid body keeps its area from frame to frame; what changes a drawn body's area in a clip is
the camera (perspective in 3D), the frame's edge, occlusion, and anything that is not rigid-body
motion: a body smeared, torn or stretched by warping pixels (the ``flow_extrapolate``
baseline), trails, bodies that grow or fade. The motion-mask IoUs cannot tell such a clip from a
simulation whose bodies went somewhere wrong; this metric can, and it does not care how a
body is drawn (colours, outline, size: each clip is compared with its own first frame).

Per clip (its paired frames; `object_level.clip_objects`: blobs of one drawn colour, colour-blind
groups, the objects of a group touching in a frame joined), per colour group g with area
A_g(0) > 0 in the first paired frame (A_g(t): the summed area of g's objects in frame t)::

    drift = Σ_g w_g · mean_t min(|ln(A_g(t) / A_g(0))|, ln 4),   w_g = A_g(0) / Σ_g A_g(0)

(a group gone from a frame counts the cap, ln 4: a fourth or four times the area), and::

    body_area_drift = max(0, drift(generated) − drift(reference))

the drift the generated clip has beyond what the reference itself shows (a body leaving the
frame, or seen nearer the camera, in the truth too). 0 for a still clip (nothing changes) and
for the truth; NaN when the generated clip shows no object in its first paired frame.

Why, and the weight it has in the headline: `visphy_core.scoring.headline` subtracts it
(``metrics.headline.penalties``) so that a clip whose bodies lose their shape cannot score above
one whose bodies move rigidly somewhere wrong; the validity study measured (docs/metrics.md,
Validity II): the flow extrapolation drifts by a median 0.067 more than the truth (10th
percentile 0.03), physics-wrong simulations by a 90th percentile of 0.002, the redrawn truths by
0.01 (the 4-px outline on thin bars, whose cores the blob finder sometimes misses: up to 0.17).

Cost: the blob finder on each clip (the generated clip's blobs are the track metrics' when they
ran, the reference's once per scene): 2D 512², 17 frames, about 50–100 ms a clip on one core.
"""

from __future__ import annotations

import math

import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import LOWER, SEQUENCE, Metric, MetricInput
from visphy_plugins.metrics import object_level as OL
from visphy_plugins.metrics import tracks as TR

CAP = math.log(4.0)  # a group's |ln area ratio| in one frame counts at most this


def group_areas(objects: OL.GenObjects, n_frames: int, frames: np.ndarray) -> np.ndarray:
    """K×G: the summed area of each colour group's objects in each of ``frames`` (indices of
    the clip's ``n_frames`` frames; a frame a pairing repeats gives the same row each time)."""
    per_frame = np.zeros((n_frames, objects.n_groups))
    np.add.at(per_frame, (objects.frame, objects.group), objects.area)
    return per_frame[frames]


def drift(areas: np.ndarray) -> float | None:
    """How much the groups' areas drift from the first frame (module docstring); None when no
    group shows in the first frame."""
    if len(areas) == 0:
        return None
    first = areas[0]
    shown = first > 0
    if not shown.any():
        return None
    ratio = areas[:, shown] / first[shown]
    with np.errstate(divide="ignore"):
        err = np.minimum(np.abs(np.log(ratio)), CAP)
    weight = first[shown] / first[shown].sum()
    return float((err.mean(axis=0) * weight).sum())


def _background(inp: MetricInput) -> tuple:
    palette = TR.scene_palette(inp.scene)
    return tuple(palette.background) if palette is not None else ()


def area_drift(inp: MetricInput, alignment) -> float:
    """``body_area_drift`` under a pairing (module docstring)."""
    ri = np.asarray(alignment.ref_idx, dtype=int)
    gi = np.asarray(alignment.gen_idx, dtype=int)
    if len(gi) == 0:
        return float("nan")
    background = _background(inp)
    gen = drift(group_areas(OL.clip_objects(inp, inp.generated, background),
                            len(inp.generated), gi))
    if gen is None:
        return float("nan")
    ref = drift(group_areas(OL.clip_objects(inp, inp.reference, background),
                            len(inp.reference), ri))
    return max(0.0, gen - (ref or 0.0))


class BodyAreaDrift(Metric):
    """How much more the drawn bodies' areas drift than the reference's (module docstring)."""

    name = "body_area_drift"
    kind = SEQUENCE
    needs = ("frames", "scene_spec")
    weights = None
    version = "1"
    family = "physics"
    direction = LOWER
    score_range = (0.0, CAP)

    def identity(self) -> str:
        return f"{super().identity()}/cap={CAP:.6f}/min_core={TR.MIN_SAMPLES}"

    def compute_sequence(self, inp: MetricInput, alignment) -> float:
        return area_drift(inp, alignment)


@hookimpl
def visphy_register_metrics(register):
    register(BodyAreaDrift())
