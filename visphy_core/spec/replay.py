"""The replay payload: one JSON description of a scene's ground truth that every reference
program draws from.

`replay_payload` is built once from a scene (its spec and trajectory) and read by every engine's
reference program (`Engine.program_from_spec`: each engine fills its own templates with it, 2D
and 3D) and by a dataset's ground-truth renderer, so they cannot disagree on what is drawn:

* ``scene_id``, ``dim``, ``width``, ``height``, ``fps``, ``n_frames``, ``background_rgb``;
* ``bodies``: in the spec's order, each ``{id, color_rgb, shape}`` (the spec's own shape) and,
  in 2D, the geometry ready to draw: ``radius`` (px) for a circle, else ``polygons`` (convex CCW
  parts in px around the body origin, y up);
* ``frame_poses[frame][body]`` in the same order: 2D ``[x_px, y_px, angle_rad]`` (origin
  bottom-left, y up, CCW), rounded to 1e-6; 3D ``[x, y, z, qx, qy, qz, qw]`` (metres, rounded to
  1 µm; quaternion to 1e-7);
* 3D only: ``camera`` (fov, near, far, position, look_at, up), ``lighting``, ``shadows``,
  ``antialias``, ``floor`` (y, colour, size) and, per body, ``opacity`` when the spec gives one
  (a translucent body).
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np


def _r(v: float, nd: int) -> float:
    return round(float(v), nd) + 0.0  # + 0.0: never "-0.0" in the JSON


def replay_payload(scene) -> dict:
    """The payload of a `visphy_core.api.scene.Scene` (``ValueError`` when it has no spec or
    trajectory: only generated benchmarks have both)."""
    spec, traj = scene.spec, scene.trajectory
    if spec is None or traj is None:
        raise ValueError(f"{scene.scene_id}: the reference program needs the scene's spec and "
                         "trajectory (generated benchmarks have both)")
    return payload_from(spec, traj["body_ids"], traj["frame_poses"], fps=scene.clip.fps,
                        n_frames=scene.clip.n_frames, width=scene.clip.width,
                        height=scene.clip.height)


def payload_from(spec: dict, body_ids, frame_poses, *, fps: float, n_frames: int,
                 width: int | None = None, height: int | None = None) -> dict:
    """The payload from a spec and per-frame poses whose bodies are ordered as ``body_ids``
    (the first ``n_frames`` frames; 3D sizes default to the spec's camera)."""
    from visphy_core.spec.spec2d import local_polygons

    dim = spec["dim"]
    order = {str(b): i for i, b in enumerate(body_ids)}
    missing = [b["id"] for b in spec["bodies"] if b["id"] not in order]
    if missing:
        raise ValueError(f"{spec.get('scene_id')}: no poses for bodies {missing}")
    poses = np.asarray(frame_poses, dtype=np.float64)[:n_frames]
    width_ = (spec["camera"]["width"] if dim == "3d" else None) if width is None else width
    height_ = (spec["camera"]["height"] if dim == "3d" else None) if height is None else height
    if width_ is None or height_ is None:
        raise ValueError("a 2D payload needs the clip's width and height")
    expected = 7 if dim == "3d" else 3
    if poses.ndim != 3 or poses.shape[2] != expected:
        raise ValueError(f"{spec.get('scene_id')}: frame_poses shape {poses.shape} is not "
                         f"(frames, bodies, {expected})")
    poses = poses[:, [order[b["id"]] for b in spec["bodies"]]]
    render = spec.get("render") or {}
    bodies = []
    for b in spec["bodies"]:
        entry: dict[str, Any] = {"id": b["id"], "color_rgb": [int(c) for c in b["color_rgb"]],
                                 "shape": b["shape"]}
        if dim == "3d" and "opacity" in b:
            entry["opacity"] = float(b["opacity"])
        if dim == "2d":
            if b["shape"]["type"] == "circle":
                entry["radius"] = float(b["shape"]["radius_px"])
            else:
                entry["polygons"] = [[[_r(v, 6) for v in pt] for pt in poly]
                                     for poly in local_polygons(b["shape"])]
        bodies.append(entry)
    payload: dict[str, Any] = {
        "scene_id": spec.get("scene_id", ""), "dim": dim,
        "width": int(width_), "height": int(height_), "fps": float(fps),
        "n_frames": int(n_frames),
        "background_rgb": [int(c) for c in render.get("background_rgb", [255, 255, 255])],
        "bodies": bodies,
    }
    if dim == "3d":
        cam, floor = spec["camera"], spec["world"]["floor"]
        payload.update({
            "camera": {"fov_deg": float(cam["fov_deg"]), "near": float(cam.get("near", 0.1)),
                       "far": float(cam.get("far", 100.0)), "position": list(cam["position"]),
                       "look_at": list(cam["look_at"]),
                       "up": list(cam.get("up", [0.0, 1.0, 0.0]))},
            "shadows": bool(render.get("shadows", False)),
            "antialias": bool(render.get("antialias", False)),
            "lighting": {k: v for k, v in (render.get("lighting") or {}).items()
                         if k in ("hemisphere", "directional")},
            "floor": {"y": float(floor["y"]), "color_rgb": list(floor["color_rgb"]),
                      "size_m": float(floor.get("size_m", 60.0))},
            "frame_poses": [[[_r(v, 6) for v in p[:3]] + [_r(v, 7) for v in p[3:]]
                             for p in frame] for frame in poses],
        })
    else:
        payload["frame_poses"] = [[[_r(v, 6) for v in p] for p in frame] for frame in poses]
    return payload


def fill(template: str, payload: dict) -> str:
    """A program template with its ``__SCENE_JSON__`` placeholder replaced by the payload."""
    return template.replace("__SCENE_JSON__", json.dumps(payload, separators=(",", ":")))

