"""Scoring cost per scene of the default (offline) metric suite on this machine.

    .venv/bin/python benchmarks/bench_metrics.py [--data-dir visphy-out/data] [--n2d 10] [--n3d 3]
        [--metrics psnr,ssim,...] [--json out.json]

Targets: ≤ 0.5 s per 2D scene (17 frames of 512², 5 fps) and ≤ 2 s per 3D scene
(75 frames of 512², 15 fps) on 2 cores, under the default protocol (visphy unaligned + aligned,
and the paper's pairing). Each video is decoded once per scene (not timed: decoding is the
pipeline's, shared by every metric) and models load once per process (the load is timed
apart, on a warm-up scene scored with an analysis and a reference text, so the text metrics'
models load there too). The generated clip of each scene is its ground truth re-timed by two
frames with the first frames held (a realistic "slightly wrong timing" clip: every pairing,
flow and track has work to do). Prints per-metric wall seconds per scene (each metric scored on
its own, the scorer's clip digests included, and all of them in one call), the CPU seconds of
this process per scene (steadier than wall time where other processes share the cores; with
several threads it counts each), torch's thread count, the per-frame cache's hits and misses,
and peak RSS. The per-frame cache starts empty for every scene and metric (no metric reuses
what another scene or metric computed).

Timings on a shared machine: run the before and after in the same go, several repeats
(``--repeat``: each scene scored that many times, the median kept).

Threads: torch's intra-op threads are set as a run sets them (`visphy_core.execute.scheduler.
pin_torch_threads`: ``$VISPHY_TORCH_THREADS``, else 1), so the figures are what a run's scoring
costs; ``--torch-threads N`` overrides. (Before, the bench took every core this process may
use: with two threads on two cores that other processes keep busy, each of FSIM's, VSI's and
ST-LPIPS' thousands of small operations waits for its slower thread, and the CPU seconds of the
torch metrics measured 3–10× those of one thread.)

``--floor`` also prints the arithmetic floor of the learned perceptual metric: ST-LPIPS'
floating-point operations per frame at its working size (counted by torch's
``FlopCounterMode`` on the real net), the throughput this machine's torch reaches on it
(frames of a batch, at the run's thread count), the distinct frames a 2D scene of a real model
needs at the fewest (the ``max_pairs`` sampled pairs of one pairing: as many reference as
generated frames) and the seconds that takes at that throughput. No other metric of the suite
can be cheaper than zero, so when that floor alone exceeds the per-scene goal the goal cannot be
met on this machine with the suite as it is.
"""

from __future__ import annotations

import argparse
import json
import os
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
    parser.add_argument("--repeat", type=int, default=1,
                        help="score each scene this many times and keep the median")
    parser.add_argument("--floor", action="store_true",
                        help="also print ST-LPIPS' GFLOP per frame and the seconds they floor")
    parser.add_argument("--torch-threads", type=int, default=None,
                        help="torch's intra-op threads (default: as a run sets them, "
                             "$VISPHY_TORCH_THREADS or 1)")
    args = parser.parse_args()
    if args.torch_threads is not None:
        os.environ["VISPHY_TORCH_THREADS"] = str(max(1, args.torch_threads))
    from visphy_core.execute.scheduler import pin_torch_threads

    pin_torch_threads()  # before any metric imports torch, as `visphy run` does

    from omegaconf import OmegaConf

    from visphy_core.api.registry import get_registry
    from visphy_core.infra.cache import Cache
    from visphy_core.scoring.score import ScoringProtocol, alignments, score_scene
    from visphy_plugins.datasets.visphybench.build import build_dataset
    from visphy_plugins.datasets.visphybench.loader import load_generated

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

    from visphy_plugins.metrics import _torch

    analysis = "The red ball falls and bounces twice."
    reference_text = "A red ball falls onto the floor and bounces."
    # warm-up: load every model once (timed apart), the text metrics' included
    warm = picked[0]
    ref = warm.reference_frames()
    t0 = time.perf_counter()
    score_scene(warm, ref, _generated(ref), available, analysis, None, cache, protocol=protocol,
                reference_text=reference_text)
    load_s = time.perf_counter() - t0

    def timed(fn) -> tuple[float, float]:
        """Median wall and CPU seconds of ``fn`` over ``--repeat`` runs, each on an empty
        per-frame cache."""
        runs = []
        for _ in range(max(1, args.repeat)):
            _torch.clear_frame_cache()
            w0, c0 = time.perf_counter(), time.process_time()
            fn()
            runs.append((time.perf_counter() - w0, time.process_time() - c0))
        wall, cpu = np.median(np.array(runs), axis=0)
        return float(wall), float(cpu)

    per_dim: dict[str, dict[str, list[float]]] = {"2d": {}, "3d": {}}
    cpu_dim: dict[str, dict[str, list[float]]] = {"2d": {}, "3d": {}}

    def record(dim: str, name: str, wall_cpu: tuple[float, float]) -> None:
        per_dim[dim].setdefault(name, []).append(wall_cpu[0])
        cpu_dim[dim].setdefault(name, []).append(wall_cpu[1])

    for scene in picked:
        ref = scene.reference_frames()
        gen = _generated(ref)
        record(scene.dim, "alignment", timed(lambda: alignments(ref, gen, protocol)))
        for m in available:
            record(scene.dim, m.name, timed(lambda m=m: score_scene(
                scene, ref, gen, [m], analysis, None, cache, protocol=protocol,
                reference_text=reference_text)))
        record(scene.dim, "TOTAL (all metrics, one call)", timed(lambda: score_scene(
            scene, ref, gen, available, analysis, None, cache, protocol=protocol,
            reference_text=reference_text)))

    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    def means(table: dict) -> dict:
        return {dim: {k: round(float(np.mean(v)), 4) for k, v in d.items()}
                for dim, d in table.items() if d}

    result = {"metrics": [m.name for m in available], "unavailable": skipped,
              "torch_threads": _torch.torch().get_num_threads(),
              "model_load_and_first_scene_s": round(load_s, 2), "peak_rss_mb": round(peak_mb),
              "seconds_per_scene": means(per_dim),
              "cpu_seconds_per_scene": means(cpu_dim),
              "frame_cache": dict(_torch.frame_cache_stats),
              "scenes": {dim: len(next(iter(d.values()), [])) for dim, d in per_dim.items()}}
    if args.floor and "st_lpips" in result["metrics"]:
        result["st_lpips_floor"] = stlpips_floor(registry.get("metrics", "st_lpips"))
    print(json.dumps(result, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))


def stlpips_floor(metric, batch: int = 4, repeats: int = 5) -> dict:
    """ST-LPIPS' GFLOP per frame at its working size, the GFLOP/s this process reaches on it and
    the seconds the fewest frames of a 2D scene cost (see the module docstring)."""
    from torch.utils.flop_counter import FlopCounterMode

    from visphy_plugins.metrics import _torch

    torch = _torch.torch()
    model = metric.model()
    side = metric.size or 512
    x = torch.rand(batch, 3, side, side) * 2 - 1
    with torch.inference_mode():
        with FlopCounterMode(display=False) as counter:
            metric.features(model, x[:1])
        gflop = counter.get_total_flops() / 1e9
        metric.features(model, x)  # warm-up
        best = min(_timed_once(lambda: metric.features(model, x)) for _ in range(repeats)) / batch
    frames = 2 * (metric.max_pairs or 17)
    return {"size": side, "gflop_per_frame": round(gflop, 2),
            "seconds_per_frame": round(best, 4), "gflop_per_s": round(gflop / best, 1),
            "torch_threads": torch.get_num_threads(),
            "fewest_frames_2d_scene": frames,
            "floor_seconds_2d_scene": round(frames * best, 3)}


def _timed_once(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
