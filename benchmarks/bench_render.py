"""Render time per scene with a warm Chromium pool, and end-to-end time of the main command.

    .venv/bin/python benchmarks/bench_render.py [--repeats 3] [--data-dir visphy-out/data]

Prints one line per measurement and a JSON summary (times in seconds, peak RSS in MiB).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--data-dir", default="visphy-out/data")
    args = parser.parse_args()

    from visphy_plugins.datasets.visphybench.build import build_dataset
    from visphy_plugins.datasets.visphybench.loader import load_generated
    from visphy_core.engine import RenderContract
    from visphy_core.video import frame_digest
    from visphy_plugins.engines.threejs import ThreeJsEngine

    scenes = load_generated(build_dataset(Path(args.data_dir), split="mini", progress=False),
                            split="mini")
    engine = ThreeJsEngine()
    t0 = time.perf_counter()
    engine.render(engine.program_from_spec(scenes[0]), RenderContract.for_scene(scenes[0]))
    cold = time.perf_counter() - t0
    times, identical = [], True
    for scene in scenes:
        program = engine.program_from_spec(scene)
        contract = RenderContract.for_scene(scene)
        digests = None
        for _ in range(args.repeats):
            t = time.perf_counter()
            result = engine.render(program, contract)
            times.append(time.perf_counter() - t)
            d = [frame_digest(f) for f in result.frames]
            identical &= digests is None or d == digests
            digests = d
            print(f"{scene.scene_id}: {times[-1]:.3f} s ({contract.n_frames} frames "
                  f"{contract.width}x{contract.height})")
    engine.close()
    summary = {
        "cold_first_render_s": round(cold, 3),
        "warm_render_s_median": round(statistics.median(times), 3),
        "warm_render_s_max": round(max(times), 3),
        "renders": len(times),
        "identical_frames_across_repeats": identical,
        "peak_rss_python_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "peak_rss_children_mib": round(
            resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, 1),
    }
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
