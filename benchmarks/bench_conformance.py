"""Engine conformance: each engine's reference program against the ground-truth clip.

    .venv/bin/python benchmarks/bench_conformance.py [--split test] [--n 10] [--engines threejs,p5]

For the first N scenes of a generated split (2D and 3D; an engine that is 2D-only skips 3D
scenes), renders `program_from_spec` with every engine and reports PSNR, SSIM and the mean
object-centre error in pixels (centroid of each body's pixels, for bodies whose colour is unique
in the scene), per engine, plus render time per clip.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np


def centre_error(truth: np.ndarray, frames: np.ndarray, colours: list[tuple[int, int, int]],
                 tol: int = 15) -> float | None:
    """Mean distance (px) between per-colour pixel centroids of two clips, over frames where the
    colour is visible in both."""
    errors = []
    for colour in colours:
        c = np.array(colour)
        for a, b in zip(truth, frames):
            ma = np.all(np.abs(a.astype(int) - c) <= tol, axis=-1)
            mb = np.all(np.abs(b.astype(int) - c) <= tol, axis=-1)
            if ma.sum() < 20 or mb.sum() < 20:
                continue
            ya, xa = np.nonzero(ma)
            yb, xb = np.nonzero(mb)
            errors.append(float(np.hypot(xa.mean() - xb.mean(), ya.mean() - yb.mean())))
    return float(np.mean(errors)) if errors else None


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--data-dir", default="visphy-out/data")
    parser.add_argument("--split", default="test")
    parser.add_argument("--n", type=int, default=10)
    parser.add_argument("--engines", default="threejs,p5,svg,manim,blender")
    parser.add_argument("--published-encoding", action="store_true",
                        help="compare with the published-style build (crf 23) instead of the "
                             "lossless one")
    args = parser.parse_args()

    from visphy_core.api.engine import RenderContract
    from visphy_core.api.registry import get_registry
    from visphy_plugins.datasets.visphybench.build import build_dataset
    from visphy_plugins.datasets.visphybench.loader import load_generated
    from visphy_plugins.metrics.pixel import psnr_frame, ssim_frame

    # conformance is about the engines, not the codec: the exact (lossless) ground truth
    root = build_dataset(Path(args.data_dir), split=args.split,
                         lossless=not args.published_encoding)
    scenes = load_generated(root, split=args.split)
    two_d = [s for s in scenes if s.dim == "2d"]
    three_d = [s for s in scenes if s.dim == "3d"]
    n3 = min(len(three_d), max(2, args.n // 5))
    chosen = two_d[: args.n - n3] + three_d[:n3]
    registry = get_registry()
    report = {}
    for name in args.engines.split(","):
        engine = registry.get("engines", name)(None)
        rows = []
        for scene in chosen:
            if scene.dim == "3d" and not engine.supports_3d:
                continue
            try:
                program = engine.program_from_spec(scene)
            except NotImplementedError:
                continue
            contract = RenderContract.for_scene(scene, timeout_s=300)
            t = time.perf_counter()
            result = engine.render(program, contract)
            wall = time.perf_counter() - t
            if not result.ok:
                rows.append({"scene": scene.scene_id, "failure": result.failure.value})
                continue
            truth = scene.reference_frames()
            colours = [tuple(b["color_rgb"]) for b in scene.spec["bodies"]]
            unique = [c for c in colours if colours.count(c) == 1]
            rows.append({
                "scene": scene.scene_id, "dim": scene.dim, "render_s": round(wall, 2),
                "psnr": round(float(np.mean([psnr_frame(a, b)
                                             for a, b in zip(truth, result.frames)])), 2),
                "ssim": round(float(np.mean([ssim_frame(a, b)
                                             for a, b in zip(truth, result.frames)])), 4),
                "centre_err_px": centre_error(truth, result.frames, unique),
            })
            print(name, json.dumps(rows[-1]))
        engine.close()
        ok = [r for r in rows if "psnr" in r]
        errs = [r["centre_err_px"] for r in ok if r["centre_err_px"] is not None]
        report[name] = {
            "scenes": len(rows), "failures": len(rows) - len(ok),
            "psnr": round(statistics.mean(r["psnr"] for r in ok), 2) if ok else None,
            "ssim": round(statistics.mean(r["ssim"] for r in ok), 4) if ok else None,
            "centre_err_px_2d": round(statistics.mean(
                r["centre_err_px"] for r in ok if r["dim"] == "2d"
                and r["centre_err_px"] is not None), 3) if errs else None,
            "render_s_median": statistics.median(r["render_s"] for r in ok) if ok else None,
        }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
