"""Statistics of the generated 2D VisPhyBench subset against the published clips and paper.

Draws every 2D (template, variant) slot as the builder does (`catalogue.draw_scene`: candidates
until one passes the validity filter), renders each accepted rollout with the exact rasteriser
and reports what the issue compares with the published VisPhyBench:

* red-ball radius (px) min / median / max          (published 17-39-56)
* non-white area per frame (%), min / median / max (published 3.3-4.4-6.6): per scene the
  median over its 17 frames, then min / median / max over scenes
* objects per scene (paper: 1,523 objects over 209 scenes, about 7.3)
* category object counts and per-scene shares, draws needed, difficulty scores / labels
* time to draw + simulate (+ features) the whole 2D catalogue, and per candidate
  (target: ≤ 0.15 s per candidate drawn, simulated and screened)
* time to rasterise each accepted rollout (target: < 1 s for a 17-frame 512² clip)

Usage: ``python benchmarks/bench_2d_stats.py [--workers 2] [--every 1] [--json out.json]``
(``--every k`` keeps every k-th slot, for a quick look).
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from visphy_core.spec.spec2d import CATEGORIES
from visphy_plugins.datasets.visphybench.catalogue import Unit, draw_scene, units

PUBLISHED = {"radius_px": (17, 39, 56), "nonwhite_pct": (3.3, 4.4, 6.6), "objects": 1523 / 209}


def nonwhite_pct(spec: dict) -> tuple[list[float], float]:
    """Per frame, the percentage of pixels not drawn in the white background; and the seconds
    the rasteriser took for the clip."""
    from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d
    from visphy_plugins.physics.box2d import simulate_2d

    rollout = simulate_2d(spec)
    start = time.perf_counter()
    frames = render_clip_2d(spec, rollout.frame_poses)
    render_s = time.perf_counter() - start
    white = np.array(spec["render"]["background_rgb"], dtype=frames.dtype)
    return [float(100.0 * np.any(f != white, axis=-1).mean()) for f in frames], render_s


def one(unit: Unit, seed: int = 0) -> dict:
    start = time.perf_counter()
    entry = draw_scene(unit, seed)
    seconds = time.perf_counter() - start
    spec = entry.spec
    nonwhite, render_s = nonwhite_pct(spec)
    red = next(b for b in spec["bodies"] if b["id"] == "red_ball")
    return {"scene_id": spec["scene_id"], "attempts": entry.attempts, "seconds": seconds,
            "red_radius": red["shape"]["radius_px"],
            "radii": [b["shape"]["radius_px"] for b in spec["bodies"]
                      if b["shape"]["type"] == "circle"],
            "categories": [b["category"] for b in spec["bodies"]],
            "n_dynamic": sum(b["dynamic"] for b in spec["bodies"]),
            "score": spec["difficulty"]["score"],
            "chaotic": spec["difficulty"]["features"]["chaotic"],
            "nonwhite": nonwhite, "render_s": render_s, "rejected": entry.rejected}


def _one(u: Unit) -> dict:
    return one(u)


def collect(every: int = 1, workers: int = 2) -> tuple[list[dict], float]:
    todo = [u for u in units() if u.dim == "2d"][::every]
    start = time.perf_counter()
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            rows = list(pool.map(_one, todo, chunksize=2))
    else:
        rows = [_one(u) for u in todo]
    return rows, time.perf_counter() - start


def summarise(rows: list[dict]) -> dict:
    n = len(rows)
    radius = np.array([r["red_radius"] for r in rows])
    nonwhite = np.array([np.median(r["nonwhite"]) for r in rows])
    objects: Counter[str] = Counter()
    present: Counter[str] = Counter()
    for r in rows:
        objects.update(r["categories"])
        present.update(set(r["categories"]))
    scores = np.array([r["score"] for r in rows])
    fixed = Counter("easy" if s <= 4.5 else "medium" if s <= 8 else "hard" for s in scores)
    rejected: Counter[str] = Counter()
    for r in rows:
        rejected.update(r["rejected"])
    attempts = np.array([r["attempts"] for r in rows])
    return {
        "scenes": n,
        "red_radius_px": [round(float(v), 1) for v in
                          (radius.min(), np.median(radius), radius.max())],
        "all_radii_px": [round(float(v), 1) for v in np.percentile(
            np.concatenate([r["radii"] for r in rows]), [0, 50, 100])],
        "nonwhite_pct": [round(float(v), 2) for v in
                         (nonwhite.min(), np.median(nonwhite), nonwhite.max())],
        "objects_per_scene": round(sum(objects.values()) / n, 2),
        "dynamic_per_scene": round(float(np.mean([r["n_dynamic"] for r in rows])), 2),
        "objects": {c: objects[c] for c in CATEGORIES},
        "objects_per_scene_by_category": {c: round(objects[c] / n, 2) for c in CATEGORIES},
        "scene_share_pct": {c: round(100.0 * present[c] / n, 1) for c in CATEGORIES},
        "attempts": {"mean": round(float(attempts.mean()), 2), "max": int(attempts.max()),
                     "first_try_pct": round(100.0 * float(np.mean(attempts == 1)), 1)},
        "rejected": dict(sorted(rejected.items())),
        "score_quartiles": [round(float(v), 2) for v in np.percentile(scores, [0, 25, 50, 75,
                                                                               100])],
        "labels_fixed_thresholds": {k: fixed[k] for k in ("easy", "medium", "hard")},
        "chaotic_pct": round(100.0 * float(np.mean([r["chaotic"] for r in rows])), 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    rows, seconds = collect(args.every, args.workers)
    out = summarise(rows)
    out["wall_s"] = round(seconds, 1)
    out["draw_simulate_cpu_s"] = round(sum(r["seconds"] for r in rows), 1)
    # the speed goals the unit tests no longer assert (wall-clock checks fail under load)
    out["seconds_per_candidate"] = round(sum(r["seconds"] for r in rows)
                                         / sum(r["attempts"] for r in rows), 3)
    out["seconds_per_candidate_target"] = 0.15
    render = np.array([r["render_s"] for r in rows])
    out["render_s_per_clip"] = {"median": round(float(np.median(render)), 3),
                                "max": round(float(render.max()), 3), "target_max": 1.0}
    out["published"] = PUBLISHED
    print(json.dumps(out, indent=1))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"summary": out, "rows": rows}, fh)


if __name__ == "__main__":
    main()
