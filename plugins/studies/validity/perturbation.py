"""Metric validity: do the metrics worsen as the physics departs from the truth?

For each 2D scene of the generated benchmark, one physical parameter at a time is pushed away
from the truth in growing steps (restitution, friction, initial speed, gravity), the scene is
re-simulated by Box2D and rendered by the same rasteriser as the ground truth, and every metric
scores the perturbed clip against the true one. A metric passes a (scene, parameter) case when
it worsens monotonically with the step: Spearman ρ between the step and the metric's
*worsening* (the value for ``lower``-is-better metrics, its negative otherwise) ≥ 0.9.

Only parameters the scene reveals (its ``ground_truth.identifiable``) are perturbed, and only in
scenes the generator does not flag as chaotic: a restitution change in a scene without a bounce,
or any change in a scene whose outcome flips with the smallest nudge, says nothing about a
metric.
"""

from __future__ import annotations

import copy
import dataclasses
import tempfile
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from scipy.stats import spearmanr

from visphy_core.api.media import ClipInfo
from visphy_core.api.metrics import LOWER, SCENE, Metric
from visphy_core.api.scene import Scene
from visphy_core.api.scoring import ScoringProtocol, score_scene
from visphy_core.api.storage import Cache

STEPS = 5
#: one step: +0.08 restitution or friction, or ×1.08 initial speed or gravity; small enough to
#: stay in the regime where the outcome changes smoothly with the parameter
RELATIVE_STEP = 0.08
#: a metric whose values over the steps differ by less than this fraction did not move
FLAT = 1e-3
PARAMS = ("restitution", "friction", "initial_speed", "gravity")
#: visphy's unaligned pairing only: alignment may legitimately absorb a pure timing change.
UNALIGNED = ScoringProtocol(unaligned=True, aligned=False, paper=False)


def _materials(spec: dict) -> Iterable[dict]:
    """Every material of ``spec``: each body's own, the default contact's and each pair's
    (also used by `interventions`)."""
    for b in spec["bodies"]:
        if "material" in b:
            yield b["material"]
    yield spec["contacts"]["default"]
    yield from spec["contacts"]["pairs"]


def _bump(spec: dict, key: str, delta: float, cap: float) -> dict:
    out = copy.deepcopy(spec)
    for m in _materials(out):
        if key in m:
            m[key] = min(cap, float(m[key]) + delta)
    return out


def perturb(spec: dict, param: str, step: int) -> dict:
    """``spec`` with ``param`` moved ``step`` steps from the truth (step 0: the truth)."""
    if param == "restitution":
        return _bump(spec, "restitution", RELATIVE_STEP * step, 0.98)
    if param == "friction":
        return _bump(spec, "friction", RELATIVE_STEP * step, 5.0)
    out = copy.deepcopy(spec)
    if param == "initial_speed":
        for b in out["bodies"]:
            v = b.get("velocity")
            if v:
                v["vx_px_s"] *= 1.0 + RELATIVE_STEP * step
                v["vy_px_s"] *= 1.0 + RELATIVE_STEP * step
        return out
    if param == "gravity":
        out["world"]["gravity_m_s2"] = [g * (1.0 + RELATIVE_STEP * step)
                                        for g in out["world"]["gravity_m_s2"]]
        return out
    raise ValueError(f"unknown parameter {param!r} (one of {', '.join(PARAMS)})")


def revealed(spec: dict, param: str) -> bool:
    ident = (spec.get("ground_truth") or {}).get("identifiable") or {}
    key = {"initial_speed": "initial_velocity"}.get(param, param)
    return bool(ident.get(key))


def clip_2d(spec: dict) -> np.ndarray:
    """The clip of a 2D spec: Box2D rollout, rendered like the ground truth (raw frames)."""
    from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d
    from visphy_plugins.physics.box2d import simulate_2d

    return render_clip_2d(spec, simulate_2d(spec).frame_poses)


def scene_of(spec: dict) -> Scene:
    """A `Scene` for a generated spec held in memory, 2D or 3D (no files: the studies render
    themselves)."""
    w = spec["world"]
    if spec["dim"] == "2d":
        width, height = w["units"]["canvas_px"]
    else:
        width, height = spec["camera"]["width"], spec["camera"]["height"]
    scene = Scene(scene_id=spec["scene_id"], dim=spec["dim"],
                  clip=ClipInfo(fps=float(w["video_fps"]), n_frames=int(w["n_frames"]),
                                width=int(width), height=int(height)),
                  video_path=Path("/nonexistent"), template_id=spec.get("template_id"))
    scene.__dict__["spec"] = spec  # the frozen dataclass's cached_property slot
    return scene


@dataclasses.dataclass
class Case:
    scene_id: str
    param: str
    values: dict[str, list[float | None]]  # column → value per step 1..STEPS


def run_case(spec: dict, param: str, metrics: list[Metric], steps: int = STEPS,
             protocol: ScoringProtocol = UNALIGNED) -> Case:
    scene = scene_of(spec)
    reference = clip_2d(spec)
    values: dict[str, list[float | None]] = {}
    with tempfile.TemporaryDirectory(prefix="visphy-validity-") as scratch:
        cache = Cache(Path(scratch), enabled=False)  # nothing reused, nothing kept
        for k in range(1, steps + 1):
            clip = clip_2d(perturb(spec, param, k))
            scores, _ = score_scene(scene, reference, clip, metrics, None, None, cache,
                                    protocol=protocol)
            for col, v in scores.items():
                values.setdefault(col, []).append(v)
    return Case(spec["scene_id"], param, values)


def chaotic(spec: dict) -> bool:
    """The generator's own flag: a tiny change of the start changes the outcome (a ball that
    bounces left or right of a peak) — no metric can be monotone in a parameter there."""
    return bool(((spec.get("difficulty") or {}).get("features") or {}).get("chaotic"))


def pick_cases(specs: list[dict], per_param: int, params: Iterable[str] = PARAMS
               ) -> list[tuple[dict, str]]:
    """Up to ``per_param`` non-chaotic 2D scenes revealing each parameter, in the order of
    ``specs``."""
    out = []
    for param in params:
        hits = [s for s in specs
                if s["dim"] == "2d" and revealed(s, param) and not chaotic(s)]
        out += [(s, param) for s in hits[:per_param]]
    return out


def run_study(specs: list[dict], metrics: list[Metric], params: Iterable[str] = PARAMS,
              steps: int = STEPS, progress: Callable[[str], None] | None = None,
              per_param: int | None = None) -> list[Case]:
    """Every revealed (scene, parameter) case of ``specs`` (2D) — or ``per_param`` scenes per
    parameter — scored by the frame and sequence ``metrics`` that are available here."""
    usable = [m for m in metrics if m.kind != SCENE and m.unavailable_reason() is None]
    if per_param is None:
        todo = [(s, p) for s in specs for p in params
                if s["dim"] == "2d" and revealed(s, p) and not chaotic(s)]
    else:
        todo = pick_cases(specs, per_param, params)
    cases = []
    for spec, param in todo:
        if progress:
            progress(f"{spec['scene_id']} {param}")
        cases.append(run_case(spec, param, usable, steps))
    return cases


def rho(values: list[float | None], direction: str) -> float | None:
    """Spearman ρ between the step and the worsening (None: undefined, e.g. a constant)."""
    if any(v is None for v in values) or len(values) < 3:
        return None
    worse = np.asarray(values, dtype=float) * (1.0 if direction == LOWER else -1.0)
    if np.ptp(worse) <= FLAT * max(1e-6, float(np.abs(worse).max())):
        return None
    r = spearmanr(np.arange(len(values)), worse).statistic
    return None if np.isnan(r) else float(r)


def summarise(cases: list[Case], directions: dict[str, str], threshold: float = 0.9,
              param: str | None = None) -> dict:
    """Per column: cases, how many pass (ρ ≥ threshold), the mean and minimum ρ; a case whose
    ρ is undefined (the metric did not move at all) counts as a failure. ``param``: only the
    cases of that parameter."""
    out = {}
    cases = [c for c in cases if param is None or c.param == param]
    for col, direction in directions.items():
        rhos = [rho(c.values[col], direction) for c in cases if col in c.values]
        defined = [r for r in rhos if r is not None]
        out[col] = {"cases": len(rhos), "passed": sum(r >= threshold - 1e-9 for r in defined),
                    "undefined": len(rhos) - len(defined),
                    "mean_rho": float(np.mean(defined)) if defined else None,
                    "min_rho": float(np.min(defined)) if defined else None,
                    "pooled_rho": pooled_rho([c.values[col] for c in cases if col in c.values],
                                             direction)}
    return out


def pooled_rho(curves: list[list[float | None]], direction: str) -> float | None:
    """Spearman ρ of the step against the mean worsening over the cases (each case measured
    from its own best step, in the metric's units): does the metric worsen with the size of
    the error on average, even where a single scene wobbles? A case where the parameter barely
    moves the metric weighs accordingly little."""
    sign = 1.0 if direction == LOWER else -1.0
    rows = [np.asarray(v, dtype=float) * sign for v in curves
            if v and not any(x is None for x in v)]
    if not rows:
        return None
    mean = np.mean([r - r.min() for r in rows], axis=0)
    if np.ptp(mean) <= FLAT * max(1e-6, float(np.abs(mean).max())):
        return None
    return float(spearmanr(np.arange(len(mean)), mean).statistic)
