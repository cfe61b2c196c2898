"""Dose series: is a score monotone in how wrong the physics is?

Per scene, four series of three doses each move one thing away from the ground truth X in
growing steps; each dose clip is drawn like X (same renderer, same spec apart from the dose)
and records its ``deviation`` (image px, 3D positions projected through the camera: the same
`interventions.deviation` as the (ii) clips), and dose 0 is X itself (`SceneOrder.truth`):

* ``gravity``: gravity ×0.9, ×0.75, ×0.5 (re-simulated); dose = 1 − factor;
* ``restitution``: every restitution (each body's material, the default contact, each pair)
  −0.1, −0.2, −0.3, clamped to `interventions.RESTITUTION_RANGE` like the (ii) clips
  (re-simulated); dose = |Δ|;
* ``launch``: the action body's (`interventions.action_body`) initial velocity turned +5°,
  +10°, +20° toward the vertical (its elevation grows: 2D counter-clockwise for a body thrown
  rightward, clockwise leftward; 3D about the horizontal axis across the velocity; a vertical
  launch turns about the world x axis), its speed kept (re-simulated); dose = degrees. A scene
  whose action body starts at rest has no launch to turn: the series is skipped there (the
  (ii) ``kick`` covers those scenes; turning a kick would make dose 5° a different scene from
  dose 0, not a small step away from it);
* ``playback``: the truth's own motion played slower, ×0.9, ×0.8, ×0.67: frame k shows the truth
  at time t₀ + (t_k − t₀)·factor (t₀: the first frame's time, so frame 0 is unchanged), its
  poses interpolated between the engine's own 1/60 s steps (`Truth.steps`; linear, the 3D
  quaternions normalised after a linear blend along the shorter arc); dose = 1 − factor. No
  re-simulation: the spec is the truth's.

A dose whose clip equals the truth's or the previous dose's (restitution clamped at 0 twice),
or that fails, is dropped (``skipped``:
``dose:<series><dose>``: why); a series that does not apply is skipped whole (``dose:<series>``).

Scoring (`series_rho`, `monotone_summary`): per scene and series, the points are dose 0 (the
truth clip) and the kept doses; Spearman ρ(dose, goodness) (goodness: the headline, or a
metric's value in its good direction: a lower-is-better value negated; ties take average ranks,
±∞ ranks as the largest / smallest, an undefined value drops its point). A series **counts**
on a scene when it has at least three points and its largest kept dose deviates from the truth
by at least `DOSE_MIN_PX` (a series that hardly moves anything, e.g. restitution where nothing
bounces, says nothing about monotonicity); it is **monotone** when ρ ≤ `MONOTONE_RHO` (−0.9).
With four points that is a strictly decreasing score or one tie between neighbours
(ρ ≈ −0.95: e.g. the truth and the smallest dose both clipped at the headline's 1); one swap of
neighbours fails (ρ = −0.8); with three points only a strictly decreasing score passes. An
undefined ρ (a constant score) is not monotone.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Callable, Iterable

import numpy as np

from visphy_core.api.metrics import HIGHER, Metric
from visphy_plugins.studies.validity.clips import (
    DOSE,
    Clip,
    ClipCache,
    ClipScore,
    NotApplicable,
    SceneOrder,
    Truth,
    changed_share,
    made,
)
from visphy_plugins.studies.validity.interventions import (
    RESTITUTION_RANGE,
    VISIBLE_PX,
    _linear,
    _set_linear,
    action_body,
    deviation,
    with_gravity,
    with_material,
)

GRAVITY_DOSES = (0.9, 0.75, 0.5)          # gravity factors
RESTITUTION_DOSES = (-0.1, -0.2, -0.3)    # restitution deltas (clamped)
LAUNCH_DOSES_DEG = (5.0, 10.0, 20.0)      # launch elevation turned by, degrees
PLAYBACK_DOSES = (0.9, 0.8, 0.67)         # playback speed factors
MONOTONE_RHO = -0.9
DOSE_MIN_PX = VISIBLE_PX                  # a series counts when its largest dose moves ≥ 2 px

#: (spec, poses) for one dose, or raises `NotApplicable`
DoseFn = Callable[[Truth, float], "tuple[dict, np.ndarray]"]


@dataclasses.dataclass(frozen=True)
class Series:
    """One dose series: ``make(truth, value)`` → (spec, per-frame poses) at each of ``values``;
    ``dose(value)`` how far that is from the truth (0 at the truth, growing); ``label(value)``
    the dose clip's name."""

    name: str
    values: tuple[float, ...]
    make: DoseFn
    dose: Callable[[float], float]
    label: Callable[[float], str]
    what: Callable[[float], str]


def _simulated(truth: Truth, spec: dict) -> tuple[dict, np.ndarray]:
    return spec, truth.renderer.simulate(spec)


def gravity_dose(truth: Truth, factor: float) -> tuple[dict, np.ndarray]:
    return _simulated(truth, with_gravity(truth.spec, factor))


def restitution_dose(truth: Truth, delta: float) -> tuple[dict, np.ndarray]:
    lo, hi = RESTITUTION_RANGE
    return _simulated(truth, with_material(truth.spec, "restitution",
                                           lambda e: min(hi, max(lo, e + delta))))


def _up(spec: dict) -> np.ndarray:
    g = np.asarray(spec["world"].get("gravity_m_s2", [0.0, -9.8, 0.0]), dtype=np.float64)
    return -g / np.linalg.norm(g) if np.linalg.norm(g) > 1e-12 else np.array([0.0, 1.0, 0.0])


def turned(vel: np.ndarray, degrees: float, dim: str, up: np.ndarray | None = None
           ) -> np.ndarray:
    """``vel`` turned ``degrees`` toward the vertical (its elevation grows), its speed kept.
    2D (x right, y up): counter-clockwise when it points rightward (vx ≥ 0), else clockwise.
    3D: about the horizontal axis across it (``vel`` × ``up``); a vertical ``vel`` about x."""
    a = math.radians(degrees)
    if dim == "2d":
        a = a if vel[0] >= 0 else -a
        c, s = math.cos(a), math.sin(a)
        return np.array([c * vel[0] - s * vel[1], s * vel[0] + c * vel[1]])
    up = np.array([0.0, 1.0, 0.0]) if up is None else up
    axis = np.cross(vel, up)
    n = np.linalg.norm(axis)
    axis = axis / n if n > 1e-9 * max(1.0, np.linalg.norm(vel)) else np.array([1.0, 0.0, 0.0])
    # Rodrigues: v cos a + (k × v) sin a + k (k · v)(1 − cos a)
    return (vel * math.cos(a) + np.cross(axis, vel) * math.sin(a)
            + axis * float(axis @ vel) * (1.0 - math.cos(a)))


def launch_dose(truth: Truth, degrees: float) -> tuple[dict, np.ndarray]:
    spec = copy.deepcopy(truth.spec)
    bid = action_body(spec)
    if bid is None:
        raise NotApplicable("no dynamic body")
    body = next(b for b in spec["bodies"] if b["id"] == bid)
    vel = _linear(body, spec["dim"])
    if not np.any(vel):
        raise NotApplicable(f"the action body ({bid}) starts at rest: no launch to turn")
    _set_linear(body, spec["dim"], turned(vel, degrees, spec["dim"], _up(spec)))
    return _simulated(truth, spec)


def slowed_poses(truth: Truth, factor: float) -> np.ndarray:
    """The truth's per-frame poses played at ``factor`` of its speed: frame k at time
    t₀ + (t_k − t₀)·factor, interpolated between the rollout's steps (`Truth.steps`)."""
    if truth.steps is None:
        raise NotApplicable("the truth's rollout steps are not kept (the renderer has no "
                            "rollout)")
    steps, frame_steps = truth.steps
    frame_steps = np.asarray(frame_steps, dtype=np.float64)
    at = frame_steps[0] + (frame_steps - frame_steps[0]) * float(factor)
    lo = np.clip(np.floor(at).astype(np.int64), 0, len(steps) - 1)
    hi = np.minimum(lo + 1, len(steps) - 1)
    w = (at - lo)[:, None, None]
    a, b = steps[lo], steps[hi]
    if steps.shape[-1] == 7:  # 3D: x y z, then a quaternion (x y z w): the shorter arc
        b = b.copy()
        flip = np.sum(a[..., 3:] * b[..., 3:], axis=-1) < 0
        b[..., 3:][flip] *= -1.0
    out = a * (1.0 - w) + b * w
    if steps.shape[-1] == 7:
        out[..., 3:] /= np.linalg.norm(out[..., 3:], axis=-1, keepdims=True)
    return out


def playback_dose(truth: Truth, factor: float) -> tuple[dict, np.ndarray]:
    return copy.deepcopy(truth.spec), slowed_poses(truth, factor)


SERIES: list[Series] = [
    Series("gravity", GRAVITY_DOSES, gravity_dose, lambda f: round(1.0 - f, 6),
           lambda f: f"gravity_x{f:g}", lambda f: f"gravity ×{f:g}"),
    Series("restitution", RESTITUTION_DOSES, restitution_dose, lambda d: abs(d),
           lambda d: f"restitution{d:+g}",
           lambda d: f"restitution {d:+g} (clamped to [{RESTITUTION_RANGE[0]:g}, "
                     f"{RESTITUTION_RANGE[1]:g}])"),
    Series("launch", LAUNCH_DOSES_DEG, launch_dose, lambda a: a, lambda a: f"launch{a:+g}",
           lambda a: f"the action body's launch turned {a:+g}° toward the vertical"),
    Series("playback", PLAYBACK_DOSES, playback_dose, lambda f: round(1.0 - f, 6),
           lambda f: f"playback_x{f:g}", lambda f: f"the truth's motion played at ×{f:g} speed"),
]


def series_named(names: Iterable[str]) -> list[Series]:
    """The `SERIES` of these names (in `SERIES`' order); ``KeyError`` for an unknown one."""
    names = list(names)
    known = {s.name for s in SERIES}
    bad = [n for n in names if n not in known]
    if bad:
        raise KeyError(f"unknown dose series {', '.join(bad)} (one of {', '.join(known)})")
    return [s for s in SERIES if s.name in names]


NOT_APPLICABLE = "does not apply: "


def dose_clips(truth: Truth, series: list[Series] | None = None,
               skipped: dict[str, str] | None = None,
               cache: ClipCache | None = None) -> Iterable[Clip]:
    """Each series' dose clips (kind ``dose``, in growing dose), one at a time; a dose that
    fails or repeats the truth or the previous dose goes into ``skipped`` (``dose:<name>``:
    why), a series that does not apply to the scene too (``dose:<series>``)."""
    skipped = {} if skipped is None else skipped
    for s in SERIES if series is None else series:
        last: np.ndarray | None = None  # the last kept dose's frames

        def make(value: float, prev: np.ndarray | None, s: Series = s) -> Clip | str:
            what = s.what(value)
            try:
                spec, poses = s.make(truth, value)
                frames = truth.renderer.draw(spec, poses)
            except NotApplicable as exc:
                return NOT_APPLICABLE + str(exc)
            except Exception as exc:  # noqa: BLE001 - a failed dose is reported, not fatal
                return f"{what}: failed: {str(exc).splitlines()[0][:200]}"
            if np.array_equal(frames, truth.frames):
                return f"{what}: the clip equals the truth"
            if prev is not None and np.array_equal(frames, prev):
                return f"{what}: the clip equals the previous dose's"
            return Clip(s.label(value), DOSE, what, frames, changed_share(frames, truth.frames),
                        deviation(truth, spec, poses), [], s.name, s.dose(value))

        for value in s.values:
            key = f"dose:{s.label(value)}"
            clip = made(truth, DOSE, s.label(value), lambda v=value, p=last: make(v, p),
                        skipped, key, cache)
            if clip is None:
                if skipped[key].startswith(NOT_APPLICABLE):
                    skipped[f"dose:{s.name}"] = skipped.pop(key)[len(NOT_APPLICABLE):]
                    break
                continue
            last = clip.frames
            yield clip


# ------------------------------------------------------------------------------ scoring
def _rankable(v: float | None) -> bool:
    return v is not None and not (isinstance(v, float) and math.isnan(v))


def spearman(x: list[float], y: list[float]) -> float | None:
    """Spearman ρ (average ranks for ties; ±∞ rank at the ends); None for fewer than 3 pairs
    or a constant side."""
    from scipy.stats import rankdata

    if len(x) < 3 or len(x) != len(y):
        return None
    rx, ry = rankdata(np.asarray(x, dtype=np.float64)), rankdata(np.asarray(y,
                                                                            dtype=np.float64))
    if np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return None
    return float(np.corrcoef(rx, ry)[0, 1])


def goodness(value: float, direction: str) -> float:
    return float(value) if direction == HIGHER else -float(value)


def series_points(res: SceneOrder, series: str, get: Callable[[ClipScore], float | None]
                  ) -> tuple[list[float], list[float], float]:
    """(doses, values, the largest kept dose's deviation) of one series on one scene: dose 0 is
    the truth clip; points whose value is undefined are left out."""
    clips = sorted((c for c in res.doses if c.series == series), key=lambda c: c.dose)
    far = max((c.deviation or 0.0 for c in clips), default=0.0)
    doses, values = [], []
    for dose, c in [(0.0, res.truth)] + [(c.dose, c) for c in clips]:
        if c is None:
            continue
        v = get(c)
        if _rankable(v):
            doses.append(float(dose))
            values.append(float(v))
    return doses, values, far


def series_rho(res: SceneOrder, get: Callable[[ClipScore], float | None],
               direction: str = HIGHER, min_px: float = DOSE_MIN_PX) -> dict[str, float | None]:
    """Per series that counts on this scene (at least 3 points, the largest dose moving
    ``min_px``): Spearman ρ(dose, goodness); a constant score gives None."""
    out: dict[str, float | None] = {}
    for name in dict.fromkeys(c.series for c in res.doses):
        doses, values, far = series_points(res, name, get)
        if len(doses) < 3 or far < min_px:
            continue
        out[name] = spearman(doses, [goodness(v, direction) for v in values])
    return out


def monotone(rho: float | None, threshold: float = MONOTONE_RHO) -> bool:
    return rho is not None and rho <= threshold + 1e-12


def monotone_summary(results: list[SceneOrder], get: Callable[[ClipScore], float | None],
                     direction: str = HIGHER, threshold: float = MONOTONE_RHO,
                     min_px: float = DOSE_MIN_PX) -> dict:
    """The share of (scene, series) cases where the score falls with the dose (``cases``,
    ``monotone``, ``share``), per series (and its mean ρ over the cases where ρ is defined),
    and the share of scenes where every counted series is monotone (``scenes``,
    ``scenes_monotone``, ``share_scenes``)."""
    per: dict[str, dict] = {}
    cases = ok = scenes = scenes_ok = 0
    for res in results:
        rhos = series_rho(res, get, direction, min_px)
        if not rhos:
            continue
        scenes += 1
        scenes_ok += all(monotone(r, threshold) for r in rhos.values())
        for name, rho in rhos.items():
            row = per.setdefault(name, {"cases": 0, "monotone": 0, "rhos": []})
            row["cases"] += 1
            row["monotone"] += monotone(rho, threshold)
            if rho is not None:
                row["rhos"].append(rho)
            cases += 1
            ok += monotone(rho, threshold)
    return {"cases": cases, "monotone": ok, "share": ok / cases if cases else None,
            "scenes": scenes, "scenes_monotone": scenes_ok,
            "share_scenes": scenes_ok / scenes if scenes else None,
            "per_series": {name: {"cases": r["cases"], "monotone": r["monotone"],
                                  "share": r["monotone"] / r["cases"],
                                  "mean_rho": float(np.mean(r["rhos"])) if r["rhos"] else None}
                           for name, r in per.items()}}


def monotone_table(results: list[SceneOrder], metrics: list[Metric],
                   threshold: float = MONOTONE_RHO, min_px: float = DOSE_MIN_PX
                   ) -> dict[str, dict]:
    """`monotone_summary` for the headline (row ``headline``) and every metric (raw values in
    the metric's good direction)."""
    rows = {"headline": monotone_summary(results, lambda c: c.headline, HIGHER, threshold,
                                         min_px)}
    for m in metrics:
        rows[m.name] = monotone_summary(results, lambda c, n=m.name: c.scores.get(n),
                                        m.direction, threshold, min_px)
    return rows
