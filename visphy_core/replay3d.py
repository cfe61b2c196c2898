"""The 3D replay page: ground-truth poses replayed by three.js in Chromium.

`replay_html_3d` fills ``visphy_core/replay3d.html`` with a JSON payload (camera, lights, floor,
bodies' shapes and colours, per-frame poses); it is a pure function of (spec, poses, fps,
n_frames). The threejs engine's reference program for 3D scenes is this page, and the generated
benchmark's ground-truth renderer (`visphy_plugins.datasets.visphybench.render3d`) renders the
same page, so both draw exactly the same thing.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def _template_path() -> Path:
    """visphy_core/replay3d.html: the replay page of the ground truth (the threejs engine's
    reference program for 3D scenes is the same page)."""
    return Path(__file__).with_name("replay3d.html")


def _round(v: float, nd: int) -> float:
    return round(float(v), nd) + 0.0


def replay_payload_3d(spec: dict, frame_poses, fps: float, n_frames: int) -> dict:
    """The JSON the replay page reads (poses rounded to 1 µm and 1e-7)."""
    poses = np.asarray(frame_poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (len(spec["bodies"]), 7):
        raise ValueError(f"{spec.get('scene_id')}: frame_poses shape {poses.shape} is not "
                         f"(frames, {len(spec['bodies'])}, 7)")
    cam, render, floor = spec["camera"], spec["render"], spec["world"]["floor"]
    return {
        "width": int(cam["width"]), "height": int(cam["height"]), "fps": float(fps),
        "n_frames": int(n_frames),
        "camera": {"fov_deg": float(cam["fov_deg"]), "near": float(cam.get("near", 0.1)),
                   "far": float(cam.get("far", 100.0)), "position": list(cam["position"]),
                   "look_at": list(cam["look_at"]), "up": list(cam.get("up", [0.0, 1.0, 0.0]))},
        "background_rgb": list(render["background_rgb"]),
        "shadows": bool(render.get("shadows", False)),
        "lighting": {"hemisphere": render["lighting"]["hemisphere"],
                     "directional": render["lighting"]["directional"]},
        "floor": {"y": float(floor["y"]), "color_rgb": list(floor["color_rgb"]),
                  "size_m": float(floor.get("size_m", 60.0))},
        "bodies": [{"id": b["id"], "color_rgb": list(b["color_rgb"]), "shape": b["shape"]}
                   for b in spec["bodies"]],
        "frame_poses": [[[_round(v, 6) for v in p[:3]] + [_round(v, 7) for v in p[3:]]
                         for p in frame] for frame in poses],
    }


def replay_html_3d(spec: dict, frame_poses, fps: float, n_frames: int) -> str:
    """The self-contained replay page (loads /vendor/three.min.js, calls setupRecording)."""
    payload = replay_payload_3d(spec, frame_poses, fps, n_frames)
    html = _template_path().read_text()
    return html.replace("__SCENE_JSON__", json.dumps(payload, separators=(",", ":")))
