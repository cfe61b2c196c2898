"""Variance-normalised scores (after Physics-IQ's "physical variance"): every frame and sequence
metric re-expressed between two anchors the scene itself sets.

Physics-IQ films each scenario twice and calls the agreement of the two takes the best any model can
hope for. visphy's takes are simulations, so the second take is made: the **twin** is the ground
truth re-simulated (by the physics plugin its spec names) after an imperceptible nudge of its
initial state, then replayed by the engine's trusted reference program under the scene's clip
contract. What the twin scores against the ground truth is the **ceiling** ``c``: the physics known
only up to what no viewer could see, drawn by the engine being evaluated. The **floor** ``f`` is
what the first key frame held for the whole clip scores (the run's fallback clip, "nothing moves" —
the clip that beat every real model on PSNR in the paper's published results). A model's value ``m``
becomes

    norm = (m − f) / (c − f)

so 1 means "as close to the ground truth as an imperceptibly different ground truth", 0 means
"no better than a frozen frame", and the scale is the same for every metric and direction (both
↑). Values above 1 (closer than the twin) and below 0 (worse than frozen) are kept, not clipped.
Where the anchors do not separate — ``c`` not strictly better than ``f`` in the metric's
direction (nothing visible moves, or a chaotic scene whose twin drifts further than a frozen
clip), or an anchor undefined — the normalised value is None and ``normalisation.json`` says why.

The nudge (`twin_spec`): every dynamic body is moved by `NUDGE_PX` (2D) or `NUDGE_M` (3D) in a
horizontal direction (horizontal, so no resting contact is pushed into its support) and its
initial velocity scaled by 1 ± `SPEED_JITTER`; directions and signs come from a generator seeded
by the scene id, so the twin is deterministic. Static bodies, materials, gravity and the clip
contract are untouched.

Columns: ``norm.<metric>`` for the program's video under the unaligned (visphy) pairing, and
``spec.norm.<metric>`` for the spec track; both anchors are scored under that same pairing.
Anchors are content-cached like every score, so a scene's twin is rendered and scored once per
engine and reused by every model and run.
"""

from __future__ import annotations

import copy
import hashlib
import math
from typing import Any

import numpy as np

from visphy_core.api.metrics import HIGHER
from visphy_core.api.scene import Scene
from visphy_core.results.columns import NORM_PREFIX, norm_column  # noqa: F401

NUDGE_PX = 0.25        # 2D: a quarter pixel
NUDGE_M = 0.001        # 3D: 1 mm (≈ 0.1 px at the benchmark's camera distances)
SPEED_JITTER = 0.002   # relative
VERSION = "twin/1"     # the perturbation's definition (recorded in normalisation.json)


def twin_spec(spec: dict) -> dict:
    """``spec`` with every dynamic body imperceptibly nudged (see the module docstring)."""
    seed = int.from_bytes(hashlib.sha256(f"{VERSION}:{spec.get('scene_id', '')}".encode())
                          .digest()[:8], "little")
    rng = np.random.default_rng(seed)
    out = copy.deepcopy(spec)
    for body in out.get("bodies") or []:
        if not body.get("dynamic", False):
            continue
        angle = float(rng.uniform(0.0, 2.0 * math.pi))
        scale = 1.0 + SPEED_JITTER * float(rng.choice([-1.0, 1.0]))
        pose = body.get("pose") or {}
        vel = body.get("velocity") or {}
        if out["dim"] == "2d":  # the only horizontal directions: left or right
            pose["x_px"] = float(pose.get("x_px", 0.0)) + NUDGE_PX * math.copysign(
                1.0, math.cos(angle))
            for key in ("vx_px_s", "vy_px_s", "omega_rad_s"):
                if key in vel:
                    vel[key] = float(vel[key]) * scale
        else:
            pos = [float(v) for v in pose.get("position_m", [0.0, 0.0, 0.0])]
            pos[0] += NUDGE_M * math.cos(angle)
            pos[2] += NUDGE_M * math.sin(angle)
            pose["position_m"] = pos
            for key in ("linear_m_s", "angular_rad_s"):
                if key in vel:
                    vel[key] = [float(v) * scale for v in vel[key]]
    return out


def twin_scene(scene: Scene, timeout_s: float = 60.0) -> Scene:
    """``scene`` with the twin's spec and trajectory (raises `SpecTrackError` when the scene
    has no spec or the simulation fails)."""
    from visphy_core.spec.spec_track import SpecTrackError, simulated_scene

    if scene.spec is None:
        raise SpecTrackError("the scene has no ground-truth spec to re-simulate (only "
                             "generated benchmarks have one)")
    return simulated_scene(scene, twin_spec(scene.spec), timeout_s=timeout_s)


def perturbation() -> dict[str, Any]:
    return {"version": VERSION, "nudge_px_2d": NUDGE_PX, "nudge_m_3d": NUDGE_M,
            "speed_jitter": SPEED_JITTER}


def normalised(value: float | None, floor: float | None, ceiling: float | None,
               direction: str) -> tuple[float | None, str | None]:
    """(norm, None) or (None, why)."""
    if value is None or not math.isfinite(value):
        return None, "no score to normalise"
    if floor is None or ceiling is None or not (math.isfinite(floor) and math.isfinite(ceiling)):
        return None, "an anchor is undefined on this scene"
    gap = (ceiling - floor) if direction == HIGHER else (floor - ceiling)
    if not gap > 1e-12 * max(1.0, abs(floor), abs(ceiling)):
        return None, ("the twin is not better than the frozen clip on this scene "
                      f"(ceiling {ceiling:.6g}, floor {floor:.6g})")
    return (value - floor) / (ceiling - floor), None
