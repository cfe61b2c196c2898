"""Screening of generated 3D candidates: why a rollout is rejected (`validity_problems_3d`:
overlap, off-screen, static, tunnelling, speed cap) and what makes a scene hard
(`difficulty_features_3d`: bodies, contacts, rotation, sensitivity to a 1 mm nudge, occlusion).
"""

from __future__ import annotations

import copy

import numpy as np

from visphy_core.api.spec import FLOOR_ID, RED_RGB, bounding_radius

OVERLAP_M = 1e-3
MIN_MOTION_M = 0.05
FLOOR_TUNNEL_M = -0.05
REGION_M = 50.0
SPEED_CAP_M_S = 50.0
PERTURB_M = 1e-3
CHAOTIC_PX = 16.0
ROTATION_DEG = 30.0
REASONS = ("overlap", "offscreen", "static", "tunnelling", "speed_cap")


# ------------------------------------------------------------------------- screening
def action_index_3d(spec: dict) -> int | None:
    """Index of the action ball: id "red_ball", else the first dynamic red sphere."""
    for i, b in enumerate(spec["bodies"]):
        if b["id"] == "red_ball":
            return i
    for i, b in enumerate(spec["bodies"]):
        if b["dynamic"] and tuple(b["color_rgb"]) == RED_RGB and b["shape"]["type"] == "sphere":
            return i
    return None


def _last_step(spec: dict, rollout) -> int:
    from visphy_plugins.physics.cannon import total_steps_3d

    return min(total_steps_3d(spec), len(rollout.step_poses) - 1)


def validity_problems_3d(spec: dict, rollout) -> list[str]:
    """Reason keys (subset of `REASONS`, in that order) why a simulated 3D candidate is unusable.

    overlap: cannon finds an interpenetration deeper than 1 mm in the initial state (pairs of
    static bodies are never tested: scenery may touch or intersect); offscreen: a body's centre
    projects outside the image (or lies behind the camera) at t = 0; static: no dynamic body
    moves more than 5 cm; tunnelling: a dynamic body's centre goes below y = -0.05 m or beyond
    |x| or |z| = 50 m, or beyond the drawn floor (``world.floor.size_m``, where it would be seen
    floating past the floor's edge); speed_cap: a body moves faster than 50 m/s between two steps.
    """
    from visphy_plugins.datasets.visphybench.detection3d import project_points

    problems = []
    if any(depth > OVERLAP_M for depth in rollout.initial_penetration_m.values()):
        problems.append("overlap")
    cam = spec["camera"]
    pix, depth = project_points(spec, rollout.step_poses[0, :, :3], return_depth=True)
    if np.any(depth <= cam.get("near", 0.1)) or np.any(
            (pix[:, 0] < 0) | (pix[:, 0] > cam["width"]) | (pix[:, 1] < 0)
            | (pix[:, 1] > cam["height"])):
        problems.append("offscreen")
    dyn = np.array([b["dynamic"] for b in spec["bodies"]], dtype=bool)
    poses = rollout.step_poses[:_last_step(spec, rollout) + 1]
    if not dyn.any() or np.linalg.norm(poses[:, dyn, :3] - poses[0, dyn, :3], axis=2).max() \
            <= MIN_MOTION_M:
        problems.append("static")
    if dyn.any():
        region = min(REGION_M, float(spec["world"]["floor"].get("size_m", 2 * REGION_M)) / 2.0)
        p = poses[:, dyn, :3]
        if np.any(p[..., 1] < spec["world"]["floor"]["y"] + FLOOR_TUNNEL_M) or np.any(
                np.abs(p[..., 0]) > region) or np.any(np.abs(p[..., 2]) > region):
            problems.append("tunnelling")
    if len(poses) > 1:
        speed = np.linalg.norm(np.diff(poses[:, :, :3], axis=0), axis=2).max() / float(
            spec["world"]["dt_s"])
        if speed > SPEED_CAP_M_S:
            problems.append("speed_cap")
    return problems


def _projected_circles(spec: dict, frame_poses: np.ndarray, radii: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Projected centres (F×B×2) and bounding-circle radii (F×B, px) of the bodies."""
    from visphy_plugins.datasets.visphybench.detection3d import camera_basis, project_points

    f, b = frame_poses.shape[:2]
    pix, depth = project_points(spec, frame_poses[:, :, :3].reshape(-1, 3), return_depth=True)
    _, _, _, f_y, _, height = camera_basis(spec)
    depth = np.maximum(depth, 1e-6).reshape(f, b)
    return pix.reshape(f, b, 2), f_y * radii[None, :] / depth * height / 2.0


def sensitivity_px_3d(spec: dict, rollout) -> float:
    """Max final-frame displacement (px) of any body's projected centre when the action ball
    starts 1 mm further along +x (one extra simulation)."""
    from visphy_plugins.datasets.visphybench.detection3d import project_points
    from visphy_plugins.physics.cannon import simulate_3d

    idx = action_index_3d(spec)
    if idx is None:
        return 0.0
    perturbed = copy.deepcopy(spec)
    perturbed["bodies"][idx]["pose"]["position_m"][0] += PERTURB_M
    other = simulate_3d(perturbed, n_steps=int(rollout.frame_steps[-1]))
    a = project_points(spec, rollout.frame_poses[-1, :, :3])
    b = project_points(spec, other.frame_poses[-1, :, :3])
    return float(np.linalg.norm(a - b, axis=1).max())


def difficulty_features_3d(spec: dict, rollout, sensitivity: bool = True) -> dict:
    """Difficulty features of a simulated 3D scene (keys shared with the 2D features).

    n_bodies, n_dynamic; n_contacts: distinct body pairs (floor excluded) that touch during the
    clip; max_rotation_deg: largest rotation of a non-spherical dynamic body from its initial
    orientation over every step, rotation_over_30deg; sensitivity_px: `sensitivity_px_3d`,
    chaotic: above 16 px; occlusion: fraction of frames in which the projected bounding circles
    (bounding sphere of each body) of two dynamic bodies overlap (static scenery such as a ramp
    always overlaps what rolls on it, so it is left out).
    """
    bodies = spec["bodies"]
    dyn = np.array([b["dynamic"] for b in bodies], dtype=bool)
    last = _last_step(spec, rollout)
    max_rot = 0.0
    for i, b in enumerate(bodies):
        if b["dynamic"] and b["shape"]["type"] != "sphere":
            q = rollout.step_poses[:last + 1, i, 3:7]
            dots = np.clip(np.abs(q @ q[0]), 0.0, 1.0)
            max_rot = max(max_rot, float(np.degrees(2.0 * np.arccos(dots)).max()))
    pairs = {k for k, st in rollout.pair_stats.items()
             if FLOOR_ID not in k.split("|") and st["steps_touching"] > 0}
    sens = sensitivity_px_3d(spec, rollout) if sensitivity else 0.0
    occlusion = 0.0
    idx = np.flatnonzero(dyn)
    if len(idx) >= 2:
        radii = np.array([bounding_radius(b["shape"]) for b in bodies])
        centres, rad = _projected_circles(spec, rollout.frame_poses, radii)
        hit = np.zeros(len(rollout.frame_poses), dtype=bool)
        for a_i, i in enumerate(idx):
            for j in idx[a_i + 1:]:
                dist = np.linalg.norm(centres[:, i] - centres[:, j], axis=1)
                hit |= dist < rad[:, i] + rad[:, j]
        occlusion = float(hit.mean())
    return {"n_bodies": len(bodies), "n_dynamic": int(dyn.sum()), "n_contacts": len(pairs),
            "rotation_over_30deg": bool(max_rot > ROTATION_DEG),
            "max_rotation_deg": round(max_rot, 3), "sensitivity_px": round(sens, 3),
            "chaotic": bool(sens > CHAOTIC_PX), "occlusion": round(occlusion, 4)}
