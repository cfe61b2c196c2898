"""Exact, alias-free rasteriser for 2D scene specs (PHYRE look: flat palette, white background).

Why a hand-written rasteriser: the reference clips must be reproducible bit for bit and must match
what a WebGL renderer of the same spec draws, so the fill rule is stated here and nowhere else:

    pixel (column i, row j; row 0 = top) is filled by a shape iff its centre (i + 0.5, j + 0.5),
    in image coordinates with image_y = H - world_y, lies inside the shape or on its boundary.

Circles use the exact disc test (dx^2 + dy^2 <= r^2); boxes, polygons and compound parts are
convex CCW polygons, rotated CCW by the body angle (y up), translated, and tested with half-planes
(cross(edge, p - v0) >= 0 for every edge). Bodies are drawn in spec order, later ones on top; no
anti-aliasing, no outlines. Work is vectorised over each shape's pixel bounding box.
"""

from __future__ import annotations

import math

import numpy as np

from visphy_core.api.spec import local_polygons, transform_points

#: PHYRE's flat palette (docs/benchmark.md).
PALETTE: dict[str, tuple[int, int, int]] = {
    "red": (243, 79, 70),       # user / action ball
    "gray": (185, 202, 210),    # dynamic
    "green": (107, 206, 187),   # dynamic (goal object)
    "blue": (24, 119, 242),     # dynamic (goal object)
    "black": (0, 0, 0),         # static
    "purple": (75, 74, 164),    # static
    "white": (255, 255, 255),   # background
}


def _pixel_window(xmin: float, xmax: float, ymin: float, ymax: float, width: int,
                  height: int) -> tuple[int, int, int, int] | None:
    """Columns [i0, i1) and rows [j0, j1) whose centres can fall in a world-space box."""
    i0 = max(0, math.ceil(xmin - 0.5))
    i1 = min(width, math.floor(xmax - 0.5) + 1)
    j0 = max(0, math.ceil(height - ymax - 0.5))
    j1 = min(height, math.floor(height - ymin - 0.5) + 1)
    if i0 >= i1 or j0 >= j1:
        return None
    return i0, i1, j0, j1


def _centres(win: tuple[int, int, int, int], height: int) -> tuple[np.ndarray, np.ndarray]:
    """World coordinates of the window's pixel centres (x column vector, y row vector)."""
    i0, i1, j0, j1 = win
    xs = np.arange(i0, i1, dtype=np.float64) + 0.5
    ys = height - (np.arange(j0, j1, dtype=np.float64) + 0.5)
    return xs[None, :], ys[:, None]


def fill_circle(img: np.ndarray, cx: float, cy: float, r: float, color: np.ndarray) -> None:
    """Fill a disc given in world px (y up) into an H×W×3 image."""
    height, width = img.shape[:2]
    win = _pixel_window(cx - r, cx + r, cy - r, cy + r, width, height)
    if win is None:
        return
    xs, ys = _centres(win, height)
    mask = (xs - cx) ** 2 + (ys - cy) ** 2 <= r * r
    i0, i1, j0, j1 = win
    img[j0:j1, i0:i1][mask] = color


def fill_convex(img: np.ndarray, poly: np.ndarray, color: np.ndarray) -> None:
    """Fill a convex CCW polygon given in world px (y up) into an H×W×3 image."""
    height, width = img.shape[:2]
    win = _pixel_window(poly[:, 0].min(), poly[:, 0].max(), poly[:, 1].min(), poly[:, 1].max(),
                        width, height)
    if win is None:
        return
    xs, ys = _centres(win, height)
    mask = np.ones((ys.shape[0], xs.shape[1]), dtype=bool)
    for k in range(len(poly)):
        x0, y0 = poly[k]
        x1, y1 = poly[(k + 1) % len(poly)]
        mask &= (x1 - x0) * (ys - y0) - (y1 - y0) * (xs - x0) >= 0
    i0, i1, j0, j1 = win
    img[j0:j1, i0:i1][mask] = color


def render_frame_2d(spec: dict, poses: np.ndarray) -> np.ndarray:
    """Render one frame (H×W×3 uint8) of a spec with body poses B×3 (x_px, y_px, angle_rad)."""
    width, height = spec["world"]["units"]["canvas_px"]
    poses = np.asarray(poses, dtype=np.float64)
    if poses.shape != (len(spec["bodies"]), 3):
        raise ValueError(f"{spec.get('scene_id')}: poses shape {poses.shape} does not match "
                         f"{len(spec['bodies'])} bodies")
    img = np.empty((height, width, 3), dtype=np.uint8)
    img[:] = np.asarray(spec["render"]["background_rgb"], dtype=np.uint8)
    for body, pose in zip(spec["bodies"], poses):
        color = np.asarray(body["color_rgb"], dtype=np.uint8)
        shape = body["shape"]
        if shape["type"] == "circle":
            fill_circle(img, pose[0], pose[1], float(shape["radius_px"]), color)
            continue
        for part in local_polygons(shape):
            fill_convex(img, transform_points(part, (pose[0], pose[1], pose[2])), color)
    return img


def render_clip_2d(spec: dict, frame_poses: np.ndarray) -> np.ndarray:
    """Render every frame of a rollout (F×B×3 poses) into an F×H×W×3 uint8 array."""
    return np.stack([render_frame_2d(spec, p) for p in frame_poses])


def initial_poses(spec: dict) -> np.ndarray:
    """The spec's own t = 0 poses as a B×3 array (x_px, y_px, angle_rad)."""
    return np.array([[b["pose"]["x_px"], b["pose"]["y_px"], b["pose"]["angle_rad"]]
                     for b in spec["bodies"]], dtype=np.float64)


def body_mask(spec: dict, index: int, pose: np.ndarray | None = None) -> np.ndarray:
    """H×W bool mask of the pixels one body covers (same fill rule), ignoring occlusion."""
    width, height = spec["world"]["units"]["canvas_px"]
    body = spec["bodies"][index]
    pose = initial_poses(spec)[index] if pose is None else np.asarray(pose, dtype=np.float64)
    img = np.zeros((height, width, 3), dtype=np.uint8)
    one = np.array([1, 1, 1], dtype=np.uint8)
    shape = body["shape"]
    if shape["type"] == "circle":
        fill_circle(img, pose[0], pose[1], float(shape["radius_px"]), one)
    else:
        for part in local_polygons(shape):
            fill_convex(img, transform_points(part, (pose[0], pose[1], pose[2])), one)
    return img[:, :, 0].astype(bool)
