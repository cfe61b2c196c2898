"""Detection context D (docs/benchmark.md) computed exactly from a scene spec instead of a detector.

Why: the paper feeds models a per-object JSON for the first frame. For generated scenes we know
the geometry, so D is derived from the spec and the frame-1 poses and is exact up to rounding.

Conventions of the output (the paper's schema): pixels, origin top-left, x to the right, y down.
* `position.center_x/center_y` is the area centroid of the drawn shape (what a detector measures;
  for symmetric shapes it is the body origin, for a jar it lies above the base);
* `bbox` is the axis-aligned box of the exact rotated geometry (not of the pixels);
* `orientation.angle_deg` (non-circles) is in image convention, **clockwise-positive** because the
  image y axis points down: angle_deg = -degrees(spec angle_rad). Bars and rectangles are
  symmetric under a half turn, so their angle is reduced to (-90, 90]; other shapes to (-180, 180].
"""

from __future__ import annotations

import math

import numpy as np

from visphy_core.api.spec import category_of, local_polygons, shape_area_centroid, transform_points

__all__ = ["category_of", "detection_from_spec"]

_DECIMALS = 2


def _r(v: float) -> float:
    return round(float(v), _DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0


def _angle_deg(angle_rad: float, half_turn_symmetric: bool) -> float:
    deg = -math.degrees(angle_rad)
    period = 180.0 if half_turn_symmetric else 360.0
    deg = math.fmod(deg, period)
    if deg > period / 2:
        deg -= period
    elif deg <= -period / 2:
        deg += period
    return _r(deg)


def _size(body: dict, category: str) -> dict[str, float]:
    shape = body["shape"]
    if shape["type"] == "circle":
        return {"radius_pixels": _r(shape["radius_px"])}
    if shape["type"] == "box":
        length, thick = shape["length_px"], shape["thickness_px"]
        if category == "line":
            return {"length_pixels": _r(max(length, thick)), "thickness_pixels": _r(min(length,
                                                                                       thick))}
        return {"width_pixels": _r(length), "height_pixels": _r(thick)}
    pts = np.concatenate(local_polygons(shape))
    ext = pts.max(axis=0) - pts.min(axis=0)
    if category == "line":  # a rectangular 4-gon used as a bar
        e = np.diff(np.vstack([pts, pts[:1]]), axis=0)
        lens = np.hypot(e[:, 0], e[:, 1])
        return {"length_pixels": _r(lens.max()), "thickness_pixels": _r(lens.min())}
    return {"width_pixels": _r(ext[0]), "height_pixels": _r(ext[1])}


def object_detection(body: dict, pose: np.ndarray, height: int) -> dict:
    """One detection object for a body at pose (x_px, y_px, angle_rad; world, y up)."""
    x, y, a = (float(v) for v in pose)
    shape = body["shape"]
    category = category_of(body)
    if shape["type"] == "circle":
        r = float(shape["radius_px"])
        cx, cy = x, y
        xmin, xmax, ymin, ymax = x - r, x + r, y - r, y + r
    else:
        _, lcx, lcy = shape_area_centroid(shape)
        cx, cy = transform_points(np.array([[lcx, lcy]]), (x, y, a))[0]
        pts = np.concatenate([transform_points(p, (x, y, a)) for p in local_polygons(shape)])
        xmin, xmax = pts[:, 0].min(), pts[:, 0].max()
        ymin, ymax = pts[:, 1].min(), pts[:, 1].max()
    # world (y up) -> image (y down): image_y = H - world_y, so the world max becomes image min.
    bbox = {"x_min": _r(xmin), "y_min": _r(height - ymax), "x_max": _r(xmax),
            "y_max": _r(height - ymin)}
    bbox["width"] = _r(xmax - xmin)
    bbox["height"] = _r(ymax - ymin)
    obj: dict = {"id": body["id"], "category": category, "color_rgb": list(body["color_rgb"]),
                 "position": {"center_x": _r(cx), "center_y": _r(height - cy)},
                 "bbox": bbox, "size": _size(body, category)}
    if shape["type"] != "circle":
        obj["orientation"] = {"angle_deg": _angle_deg(a, category in ("line", "rectangle"))}
    return obj


def detection_from_spec(spec: dict, poses_frame0: np.ndarray | None = None) -> dict:
    """Detection JSON for frame 1 of a scene; poses default to the spec's t = 0 poses."""
    width, height = spec["world"]["units"]["canvas_px"]
    if poses_frame0 is None:
        poses_frame0 = np.array([[b["pose"]["x_px"], b["pose"]["y_px"], b["pose"]["angle_rad"]]
                                 for b in spec["bodies"]])
    poses = np.asarray(poses_frame0, dtype=np.float64)
    if poses.shape != (len(spec["bodies"]), 3):
        raise ValueError(f"{spec.get('scene_id')}: poses shape {poses.shape} does not match "
                         f"{len(spec['bodies'])} bodies")
    return {
        "image_size": {"width": int(width), "height": int(height)},
        "coordinate_system": {"origin": "top_left", "x_axis": "to_right", "y_axis": "down",
                              "units": "pixels"},
        "objects": [object_detection(b, p, int(height)) for b, p in zip(spec["bodies"], poses)],
    }
