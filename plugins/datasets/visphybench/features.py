"""Difficulty features of a simulated 2D scene, and one monotone score the builder ranks.

Why features and not labels: VisPhyBench's easy/medium/hard labels come from human 1-5 ratings
(114/67/28 over 209 scenes). We cannot ask humans, so the builder ranks scenes by a score made of
things that make a clip hard to reconstruct - more moving bodies, more interactions, visible
rotation, sensitivity to the initial condition - and cuts the ranking at the paper's proportions.

Features (all deterministic: Box2D is, and the perturbation is fixed):

* ``n_bodies``, ``n_dynamic``;
* ``n_contacts``: distinct body pairs (walls excluded) that touch during the clip;
* ``max_rotation_deg``: largest |angle - initial angle| of a non-circular dynamic body over every
  step of the clip (a turning disc is invisible in PHYRE's flat look); ``rotation_over_30deg``;
* ``sensitivity_px``: the largest change of any body's final-frame position when the red ball
  starts 0.5 px further right (one extra simulation); ``chaotic``: sensitivity above 16 px;
* ``occlusion``: fraction of a body hidden by others - always 0.0 in 2D (kept for 3D scenes).
"""

from __future__ import annotations

import copy
import math

import numpy as np

from visphy_plugins.datasets.visphybench.raster2d import PALETTE
from visphy_plugins.physics.box2d import Rollout, simulate_2d, total_steps

PERTURB_PX = 0.5
CHAOTIC_PX = 16.0
ROTATION_DEG = 30.0


def _action_index(spec: dict) -> int | None:
    """Index of the action ball: id "red_ball", else the first dynamic red body."""
    for i, b in enumerate(spec["bodies"]):
        if b["id"] == "red_ball":
            return i
    red = list(PALETTE["red"])
    for i, b in enumerate(spec["bodies"]):
        if b["dynamic"] and b["color_rgb"] == red:
            return i
    return None


def sensitivity_px(spec: dict, rollout: Rollout) -> float:
    """Max final-frame displacement of any body when the action ball starts 0.5 px to the right."""
    idx = _action_index(spec)
    if idx is None:
        return 0.0
    perturbed = copy.deepcopy(spec)
    perturbed["bodies"][idx]["pose"]["x_px"] += PERTURB_PX
    other = simulate_2d(perturbed, n_steps=int(rollout.frame_steps[-1]))
    diff = other.frame_poses[-1, :, :2] - rollout.frame_poses[-1, :, :2]
    return float(np.hypot(diff[:, 0], diff[:, 1]).max())


def difficulty_features(spec: dict, rollout: Rollout) -> dict:
    """The difficulty features of a simulated scene (see the module docstring)."""
    bodies = spec["bodies"]
    dyn = np.array([b["dynamic"] for b in bodies], dtype=bool)
    turning = np.array([b["dynamic"] and b["shape"]["type"] != "circle" for b in bodies])
    last = min(total_steps(spec), len(rollout.step_poses) - 1)
    max_rot = 0.0
    if turning.any():
        ang = rollout.step_poses[:last + 1, turning, 2]
        max_rot = float(np.degrees(np.abs(ang - ang[0]).max()))
    pairs = {k for k in rollout.pair_stats if "wall_" not in k}
    sens = sensitivity_px(spec, rollout)
    return {"n_bodies": len(bodies), "n_dynamic": int(dyn.sum()), "n_contacts": len(pairs),
            "rotation_over_30deg": bool(max_rot > ROTATION_DEG),
            "max_rotation_deg": round(max_rot, 3), "sensitivity_px": round(sens, 3),
            "chaotic": bool(sens > CHAOTIC_PX), "occlusion": 0.0}


def difficulty_score(features: dict) -> float:
    """Monotone (non-decreasing in every feature) difficulty score.

    score = n_dynamic + 0.25 (n_bodies - n_dynamic) + 1.5 n_contacts
            + 2 [rotation > 30 deg] + min(max_rotation_deg, 360) / 180
            + 3 [chaotic] + 0.5 log2(1 + min(sensitivity_px, 512)) + 4 occlusion

    Moving bodies and interactions dominate (each is something a model must get right); static
    scenery adds a little; visible rotation and chaos add steps; the continuous terms break ties.
    """
    n_dyn = float(features["n_dynamic"])
    n_static = max(0.0, float(features.get("n_bodies", n_dyn)) - n_dyn)
    rot = min(float(features.get("max_rotation_deg", 0.0)), 360.0)
    sens = min(max(float(features.get("sensitivity_px", 0.0)), 0.0), 512.0)
    return (n_dyn + 0.25 * n_static + 1.5 * float(features["n_contacts"])
            + 2.0 * bool(features["rotation_over_30deg"]) + rot / 180.0
            + 3.0 * bool(features["chaotic"]) + 0.5 * math.log2(1.0 + sens)
            + 4.0 * float(features.get("occlusion", 0.0)))
