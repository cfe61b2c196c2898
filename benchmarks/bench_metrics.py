"""Scoring cost per scene of the default (offline) metric suite on this machine.

    .venv/bin/python benchmarks/bench_metrics.py [--data-dir visphy-out/data] [--n2d 10] [--n3d 3]
        [--metrics psnr,ssim,...] [--json out.json]

Targets (issue 9): ≤ 0.5 s per 2D scene (17 frames of 512², 5 fps) and ≤ 2 s per 3D scene
(75 frames of 512², 15 fps) on 2 cores, under the default protocol (visphy unaligned + aligned,
and the paper's pairing). Each video is decoded once per scene (not timed: decoding is the
pipeline's, shared by every metric) and models load once per process (the load is timed
apart, on a warm-up scene). The generated clip of each scene is its ground truth re-timed by two
frames with the first frames held (a realistic "slightly wrong timing" clip: every pairing,
flow and track has work to do). Prints per-metric seconds per scene, the total, and peak RSS.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import numpy as np


def _generated(reference: np.ndarray) -> np.ndarray:
    return np.concatenate([reference[:1], reference[:1], reference[:-2]])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--data-dir", default="visphy-out/data")
    parser.add_argument("--n2d", type=int, default=10)
    parser.add_argument("--n3d", type=int, default=3)
    parser.add_argument("--metrics", default=None,
                        help="comma-separated names (default: conf/metrics/default.yaml)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    from omegaconf import OmegaConf

    from visphy_plugins.datasets.visphybench.build import build_dataset
    from visphy_core.cache import Cache
    from visphy_plugins.datasets.visphybench.loader import load_generated
    from visphy_core.plugins import get_registry
    from visphy_core.scoring import ScoringProtocol, alignments, score_scene

    if args.metrics:
        names = args.metrics.split(",")
    else:
        conf = Path(__file__).resolve().parents[1] / "conf" / "metrics" / "default.yaml"
        names = list(OmegaConf.load(conf).names)
    registry = get_registry()
    metrics = [registry.get("metrics", n) for n in names]
    available = [m for m in metrics if m.unavailable_reason() is None]
    skipped = {m.name: m.unavailable_reason() for m in metrics if m not in available}

    root = build_dataset(Path(args.data_dir), split="sub", progress=True)
    scenes = load_generated(root, split="sub")
    picked = ([s for s in scenes if s.dim == "2d"][:args.n2d]
              + [s for s in scenes if s.dim == "3d"][:args.n3d])
    protocol = ScoringProtocol()
    import tempfile

    cache = Cache(Path(tempfile.mkdtemp(prefix="visphy-bench-metrics-")), enabled=False)

    # warm-up: load every model once (timed apart)
    warm = picked[0]
    ref = warm.reference_frames()
    t0 = time.perf_counter()
    score_scene(warm, ref, _generated(ref), available, None, None, cache, protocol=protocol,
                reference_text="a ball falls")
    load_s = time.perf_counter() - t0

    per_dim: dict[str, dict[str, list[float]]] = {"2d": {}, "3d": {}}
    for scene in picked:
        ref = scene.reference_frames()
        gen = _generated(ref)
        t0 = time.perf_counter()
        alignments(ref, gen, protocol)
        per_dim[scene.dim].setdefault("alignment", []).append(time.perf_counter() - t0)
        for m in available:
            t0 = time.perf_counter()
            score_scene(scene, ref, gen, [m], "The red ball falls and bounces twice.", None,
                        cache, protocol=protocol,
                        reference_text="A red ball falls onto the floor and bounces.")
            per_dim[scene.dim].setdefault(m.name, []).append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        score_scene(scene, ref, gen, available, "The red ball falls and bounces twice.", None,
                    cache, protocol=protocol,
                    reference_text="A red ball falls onto the floor and bounces.")
        per_dim[scene.dim].setdefault("TOTAL (all metrics, one call)", []).append(
            time.perf_counter() - t0)

    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    result = {"metrics": [m.name for m in available], "unavailable": skipped,
              "model_load_and_first_scene_s": round(load_s, 2), "peak_rss_mb": round(peak_mb),
              "seconds_per_scene": {
                  dim: {k: round(float(np.mean(v)), 4) for k, v in d.items()}
                  for dim, d in per_dim.items() if d},
              "scenes": {dim: len(next(iter(d.values()), [])) for dim, d in per_dim.items()}}
    print(json.dumps(result, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
