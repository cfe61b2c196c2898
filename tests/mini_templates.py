"""Hand-made PHYRE-style 2D scenes (the "mini" benchmark) and the generic ground-truth annotator.

Why hand-made: a handful of scenes with clearly visible, qualitatively different physics (free
fall onto a ramp, rolling, a ball dropped into a jar, sliding on an incline, a thrown ball hitting a
stack) lets the whole pipeline be exercised end to end in seconds. Every scene uses PHYRE's
conventions: 512x512 canvas, flat palette, red action ball, bars W/50 thick, 17 frames at 5 fps.

`annotate_ground_truth` is shared by every template family: it simulates the scene and fills the
difficulty features/label and the honest identifiability flags from the rollout (rules below).
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

from visphy_core.spec.spec2d import (
    PHYRE_PROFILE,
    category_of,
    shape_area_centroid,
    validate_spec,
)
from visphy_plugins.datasets.visphybench.raster2d import PALETTE, body_mask
from visphy_plugins.physics.box2d import Rollout, simulate_2d

BAR = PHYRE_PROFILE["bar_thickness_px"]  # 10.24 px
_STILL = {"vx_px_s": 0.0, "vy_px_s": 0.0, "omega_rad_s": 0.0}


# ----------------------------------------------------------------------------- body builders
def _body(bid: str, color: str, shape: dict, x: float, y: float, angle: float, dynamic: bool,
          velocity: tuple[float, float, float] | None = None) -> dict:
    body: dict[str, Any] = {"id": bid, "category": "", "dynamic": dynamic,
                            "color_rgb": list(PALETTE[color]), "shape": shape,
                            "pose": {"x_px": float(x), "y_px": float(y), "angle_rad": float(angle)}}
    if dynamic:
        vx, vy, w = velocity or (0.0, 0.0, 0.0)
        body["velocity"] = {"vx_px_s": float(vx), "vy_px_s": float(vy), "omega_rad_s": float(w)}
        body["material"] = {"density_kg_m2": PHYRE_PROFILE["density_kg_m2"],
                            "friction": PHYRE_PROFILE["friction"],
                            "restitution": PHYRE_PROFILE["restitution"]}
    body["category"] = category_of(body)
    return body


def ball(bid: str, color: str, r: float, x: float, y: float, dynamic: bool = True,
         velocity: tuple[float, float, float] | None = None) -> dict:
    """A PHYRE ball (circle of radius r px)."""
    shape = {"type": "circle", "radius_px": float(r)}
    return _body(bid, color, shape, x, y, 0.0, dynamic, velocity)


def box(bid: str, color: str, length: float, thickness: float, x: float, y: float,
        angle: float = 0.0, dynamic: bool = False) -> dict:
    """A box/bar centred at (x, y); a bar is a box with thickness BAR."""
    shape = {"type": "box", "length_px": float(length), "thickness_px": float(thickness)}
    return _body(bid, color, shape, x, y, angle, dynamic)


def jar(bid: str, color: str, width: float, height: float, x: float, y: float,
        angle: float = 0.0, dynamic: bool = True, wall: float = BAR) -> dict:
    """A U-shaped jar: base centred on the origin plus two walls standing on the base."""
    hw, ht = width / 2.0, wall / 2.0
    parts = [[[-hw, -ht], [hw, -ht], [hw, ht], [-hw, ht]],
             [[-hw, ht], [-hw + wall, ht], [-hw + wall, height], [-hw, height]],
             [[hw - wall, ht], [hw, ht], [hw, height], [hw - wall, height]]]
    return _body(bid, color, {"type": "compound", "parts_px": parts}, x, y, angle, dynamic)


def on_bar(bar: dict, along: float, above: float) -> tuple[float, float]:
    """World point `along` px from a bar's centre along its axis, `above` px over its top face."""
    a = bar["pose"]["angle_rad"]
    off = bar["shape"]["thickness_px"] / 2.0 + above
    return (bar["pose"]["x_px"] + along * math.cos(a) - off * math.sin(a),
            bar["pose"]["y_px"] + along * math.sin(a) + off * math.cos(a))


def scene(template: int, variant: int, description: str, bodies: list[dict]) -> dict:
    """Wrap bodies into a PHYRE-profile `visphy-scene/1` spec (ground truth still empty)."""
    from visphy_plugins.datasets.visphybench.blocks2d import scene2d

    spec = scene2d(template, variant, "mini", description, bodies)
    spec["seed"] = template * 1000 + variant
    return spec


# ------------------------------------------------------------------------------ the scenes
def _scene_ramp_roll() -> dict:
    ramp = box("black_bar", "black", 260, BAR, 170, 330, angle=-0.35)
    shelf = box("purple_box", "purple", 80, 40, 466, 220)
    return scene(1, 0, "red ball falls on a tilted bar, rolls off and knocks a gray ball", [
        ball("red_ball", "red", 18, 110, 470), ramp, shelf,
        ball("gray_ball", "gray", 22, 400, 22.5)])


def _scene_ball_into_jar() -> dict:
    deflector = box("black_bar", "black", 170, BAR, 215, 330, angle=-0.55)
    return scene(2, 0, "red ball bounces off a tilted bar and drops into a gray jar", [
        ball("red_ball", "red", 16, 175, 470), deflector,
        jar("gray_jar", "gray", 100, 70, 440, BAR / 2 + 0.5),
        ball("blue_ball", "blue", 20, 70, 20.5)])


def _scene_box_slides() -> dict:
    ramp = box("black_bar", "black", 300, BAR, 190, 250, angle=-0.6)
    gx, gy = on_bar(ramp, -95.0, 20.5)
    return scene(3, 0, "green box slides down a steep bar and hits a blue ball; red ball follows", [
        ball("red_ball", "red", 15, 70, 470), ramp,
        _body("green_box", "green", {"type": "box", "length_px": 40.0, "thickness_px": 40.0},
              gx, gy, -0.6, True),
        ball("blue_ball", "blue", 24, 420, 24.5),
        box("purple_box", "purple", 90, 30, 440, 400)])


def _scene_thrown_ball() -> dict:
    return scene(4, 0, "thrown red ball knocks a green ball off a gray box", [
        ball("red_ball", "red", 16, 40, 300, velocity=(100.0, 25.0, 0.0)),
        box("purple_box", "purple", 90, 30, 150, 60),
        _body("gray_box", "gray", {"type": "box", "length_px": 50.0, "thickness_px": 50.0},
              380, 25.5, 0.0, True),
        ball("green_ball", "green", 20, 380, 71.0),
        box("black_bar", "black", 140, BAR, 440, 300, angle=0.3)])


# --------------------------------------------------------------------------- annotation
def layout_problems(spec: dict) -> list[str]:
    """Bodies outside the canvas or overlapping another body at t = 0 (pixel masks)."""
    problems, masks = [], []
    for i, body in enumerate(spec["bodies"]):
        mask = body_mask(spec, i)
        full = int(round(_area(body)))
        if abs(int(mask.sum()) - full) > max(4, 0.03 * full):
            problems.append(f"{body['id']} is not entirely on screen")
        for other, omask in masks:
            if np.any(mask & omask):
                problems.append(f"{body['id']} overlaps {other}")
        masks.append((body["id"], mask))
    return problems


def _area(body: dict) -> float:
    return shape_area_centroid(body["shape"])[0]


def difficulty_of(spec: dict, rollout: Rollout) -> dict:
    """Heuristic difficulty: score = n_dynamic + 1.5 n_contacts + 2 rotation + 3 chaotic.

    n_contacts counts distinct body pairs (walls excluded) that touch during the clip; rotation is
    true when a non-circular dynamic body turns > 30 degrees from frame 1; chaotic is true when
    moving the red ball 1 px right changes some final position by > 16 px. Labels: easy <= 4.5,
    medium <= 8, hard above (the paper's labels come from human ratings; these are a proxy).
    """
    bodies = spec["bodies"]
    n_dynamic = sum(b["dynamic"] for b in bodies)
    pairs = {k for k in rollout.pair_stats if "wall_" not in k}
    rotation = False
    for i, b in enumerate(bodies):
        if b["dynamic"] and b["shape"]["type"] != "circle":
            turn = np.abs(rollout.frame_poses[:, i, 2] - rollout.frame_poses[0, i, 2]).max()
            rotation |= bool(turn > math.radians(30))
    perturbed = copy.deepcopy(spec)
    red = [b for b in perturbed["bodies"] if b["id"] == "red_ball"]
    chaotic = False
    if red:
        red[0]["pose"]["x_px"] += 1.0
        other = simulate_2d(perturbed)
        diff = np.hypot(*(other.frame_poses[-1, :, :2] - rollout.frame_poses[-1, :, :2]).T)
        chaotic = bool(diff.max() > 16.0)
    score = n_dynamic + 1.5 * len(pairs) + 2.0 * rotation + 3.0 * chaotic
    label = "easy" if score <= 4.5 else "medium" if score <= 8 else "hard"
    return {"label": label, "score": score,
            "features": {"n_dynamic": n_dynamic, "n_contacts": len(pairs),
                         "rotation_over_30deg": rotation, "chaotic": chaotic}}


def identifiable_of(spec: dict, rollout: Rollout) -> dict:
    """Which physical parameters the clip can reveal (visphybench's `identifiable`)."""
    from visphy_plugins.datasets.visphybench.identifiable import identifiable_params

    return identifiable_params(spec, rollout)


def annotate_ground_truth(spec: dict) -> tuple[dict, Rollout]:
    """Validate, check the layout, simulate, and fill difficulty, events and identifiability."""
    problems = layout_problems(spec)
    if problems:
        raise ValueError(f"{spec['scene_id']}: bad initial layout: {'; '.join(problems)}")
    validate_spec(spec)
    out = copy.deepcopy(spec)
    rollout = simulate_2d(out)
    out["difficulty"] = difficulty_of(out, rollout)
    out["ground_truth"]["events"] = rollout.events
    out["ground_truth"]["identifiable"] = identifiable_of(out, rollout)
    validate_spec(out)
    return out, rollout


def _scene_corner_drop() -> dict:
    return scene(5, 0, "red ball falls freely, clips the corner of a purple box and rolls away", [
        ball("red_ball", "red", 20, 196, 480), box("purple_box", "purple", 100, 30, 130, 40),
        box("black_bar", "black", 120, BAR, 420, 380)])


SCENES = (_scene_ramp_roll, _scene_ball_into_jar, _scene_box_slides, _scene_thrown_ball,
          _scene_corner_drop)


def mini_scenes() -> list[tuple[dict, Rollout]]:
    """The mini scenes with their rollouts, annotated, in a fixed order."""
    return [annotate_ground_truth(make()) for make in SCENES]


def mini_specs() -> list[dict]:
    """The mini scenes, annotated (difficulty, events, identifiability), in a fixed order."""
    return [spec for spec, _ in mini_scenes()]
