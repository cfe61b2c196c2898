"""Detection context D (docs/benchmark.md) of a 3D scene, computed exactly from its spec and poses.

The camera model is three.js's PerspectiveCamera (vertical ``fov_deg``, aspect width/height,
``lookAt`` with the spec's ``up``, default +y), so `project_points` lands on the pixels the
three.js replay draws. Output follows the paper's schema: pixels, origin top-left, x to the
right, y down, continuous coordinates (pixel (i, j) covers [i, i+1) × [j, j+1)).

Per object:
* ``position`` is the projection of the body's origin (its centre of mass);
* ``bbox`` is the axis-aligned box of the projected geometry: box corners, wedge vertices and,
  for spheres, the exact silhouette (the projection of the circle where view rays graze the
  sphere);
* ``size``: spheres ``radius_pixels`` (half the mean silhouette extent); planks (``line``)
  ``length_pixels`` / ``thickness_pixels``, the extents of the projected box along and across
  the image direction of its long axis; other shapes ``width_pixels`` / ``height_pixels`` of the
  bbox;
* ``orientation.angle_deg`` (planks only): image angle of the long axis, clockwise-positive
  (y down), reduced to (-90, 90].
"""

from __future__ import annotations

import math

import numpy as np

from visphy_core.api.spec import (
    box_corners,
    category_of_3d,
    quat_to_matrix,
    shape_parts,
    transform_points_3d,
    wedge_vertices,
)

__all__ = ["camera_basis", "project_points", "sphere_silhouette", "body_image_points",
           "detection_from_spec_3d"]

_DECIMALS = 2


def _r(v: float) -> float:
    return round(float(v), _DECIMALS) + 0.0


def camera_basis(spec: dict) -> tuple[np.ndarray, np.ndarray, float, float, int, int]:
    """(eye, R, f_x, f_y, width, height): R's columns are the camera's x, y, z axes in world
    coordinates (three.js Matrix4.lookAt: z = eye - target, x = up × z, y = z × x), and
    ndc = (f_x x_c, f_y y_c) / -z_c."""
    cam = spec["camera"]
    eye = np.asarray(cam["position"], dtype=np.float64)
    target = np.asarray(cam["look_at"], dtype=np.float64)
    up = np.asarray(cam.get("up", [0.0, 1.0, 0.0]), dtype=np.float64)
    z = eye - target
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    width, height = int(cam["width"]), int(cam["height"])
    f_y = 1.0 / math.tan(math.radians(float(cam["fov_deg"])) / 2.0)
    f_x = f_y * height / width
    return eye, np.stack([x, y, z], axis=1), f_x, f_y, width, height


def project_points(spec: dict, points_world, return_depth: bool = False):
    """Pixel coordinates (N×2, top-left origin, y down) of world points through the spec's
    camera; with ``return_depth`` also the distance in front of the camera (N, metres; ≤ 0
    means behind it, where the pixel coordinates are meaningless)."""
    eye, rot, f_x, f_y, width, height = camera_basis(spec)
    pts = np.atleast_2d(np.asarray(points_world, dtype=np.float64))
    cam = (pts - eye) @ rot
    depth = -cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc_x = f_x * cam[:, 0] / depth
        ndc_y = f_y * cam[:, 1] / depth
    pix = np.stack([(ndc_x + 1.0) * 0.5 * width, (1.0 - ndc_y) * 0.5 * height], axis=1)
    return (pix, depth) if return_depth else pix


def sphere_silhouette(spec: dict, centre, radius: float, n: int = 72) -> np.ndarray:
    """World points on the circle where view rays from the camera graze the sphere (their
    projection is the sphere's exact outline)."""
    eye = np.asarray(spec["camera"]["position"], dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64)
    axis = eye - c
    d = float(np.linalg.norm(axis))
    axis = axis / d
    if d <= radius:  # camera inside the sphere: fall back to a great circle
        ring_c, ring_r = c, radius
    else:
        ring_c = c + axis * (radius * radius / d)
        ring_r = radius * math.sqrt(1.0 - (radius / d) ** 2)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u = u / np.linalg.norm(u)
    v = np.cross(axis, u)
    t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return ring_c + ring_r * (np.outer(np.cos(t), u) + np.outer(np.sin(t), v))


def body_world_points(spec: dict, body: dict, pose) -> np.ndarray:
    """World points whose projection bounds the body's image (corners, vertices, silhouettes)."""
    pose = np.asarray(pose, dtype=np.float64)
    rot = quat_to_matrix(pose[3:7])
    out = []
    for prim, offset, quat in shape_parts(body["shape"]):
        part_rot = quat_to_matrix(quat)
        kind = prim["type"]
        if kind == "sphere":
            centre = pose[:3] + rot @ offset
            out.append(sphere_silhouette(spec, centre, prim["radius_m"]))
            continue
        local = box_corners(prim["size_m"]) if kind == "box" else wedge_vertices(
            prim["length_m"], prim["height_m"], prim["width_m"])
        out.append(transform_points_3d(local @ part_rot.T + offset, pose))
    return np.concatenate(out)


def body_image_points(spec: dict, body: dict, pose) -> np.ndarray:
    """Projected outline points (pixels) of one body at a pose."""
    return project_points(spec, body_world_points(spec, body, pose))


def _angle_deg(dx: float, dy: float) -> float:
    deg = math.degrees(math.atan2(dy, dx))
    deg = math.fmod(deg, 180.0)
    if deg > 90.0:
        deg -= 180.0
    elif deg <= -90.0:
        deg += 180.0
    return _r(deg)


def object_detection_3d(spec: dict, body: dict, pose) -> dict:
    """One detection object for a body at a pose (x, y, z, qx, qy, qz, qw)."""
    pose = np.asarray(pose, dtype=np.float64)
    category = category_of_3d(body)
    centre = project_points(spec, pose[:3])[0]
    pts = body_image_points(spec, body, pose)
    xmin, ymin = pts.min(axis=0)
    xmax, ymax = pts.max(axis=0)
    bbox = {"x_min": _r(xmin), "y_min": _r(ymin), "x_max": _r(xmax), "y_max": _r(ymax),
            "width": _r(xmax - xmin), "height": _r(ymax - ymin)}
    obj: dict = {"id": body["id"], "category": category, "color_rgb": list(body["color_rgb"]),
                 "position": {"center_x": _r(centre[0]), "center_y": _r(centre[1])},
                 "bbox": bbox}
    shape = body["shape"]
    if category == "circle":
        obj["size"] = {"radius_pixels": _r(((xmax - xmin) + (ymax - ymin)) / 4.0)}
    elif category == "line" and shape["type"] == "box":
        axis = int(np.argmax(shape["size_m"]))
        half = np.zeros(3)
        half[axis] = shape["size_m"][axis] / 2.0
        ends = project_points(spec, transform_points_3d(np.stack([-half, half]), pose))
        u = ends[1] - ends[0]
        norm = float(np.hypot(*u))
        u = u / norm if norm > 1e-12 else np.array([1.0, 0.0])
        n = np.array([-u[1], u[0]])
        along, across = (pts - centre) @ u, (pts - centre) @ n
        obj["size"] = {"length_pixels": _r(along.max() - along.min()),
                       "thickness_pixels": _r(across.max() - across.min())}
        obj["orientation"] = {"angle_deg": _angle_deg(u[0], u[1])}
    else:
        obj["size"] = {"width_pixels": bbox["width"], "height_pixels": bbox["height"]}
    return obj


def detection_from_spec_3d(spec: dict, poses_frame0=None) -> dict:
    """Detection JSON for frame 1 of a 3D scene; poses (B×7) default to the spec's t = 0 poses."""
    if poses_frame0 is None:
        poses_frame0 = [list(b["pose"]["position_m"]) + list(b["pose"]["quat"])
                        for b in spec["bodies"]]
    poses = np.asarray(poses_frame0, dtype=np.float64)
    if poses.shape != (len(spec["bodies"]), 7):
        raise ValueError(f"{spec.get('scene_id')}: poses shape {poses.shape} does not match "
                         f"{len(spec['bodies'])} bodies × 7")
    cam = spec["camera"]
    return {
        "image_size": {"width": int(cam["width"]), "height": int(cam["height"])},
        "coordinate_system": {"origin": "top_left", "x_axis": "to_right", "y_axis": "down",
                              "units": "pixels"},
        "objects": [object_detection_3d(spec, b, p) for b, p in zip(spec["bodies"], poses)],
    }
