"""Render time per clip with a warm Chromium pool, per engine, the fast path against the path it
replaced, in one run.

    .venv/bin/python benchmarks/bench_render.py [--repeats 3] [--data-dir visphy-out/data]
        [--engines threejs,p5,svg] [--scenes-3d 2] [--paths fast,png] [--gap 0.5]
        [--json out.json]

Paths: ``fast`` is the default pool (raw readback, pages prepared ahead with the engine's
libraries loaded, contexts closed in the background); ``png`` is the path it replaced (PNG
readback, every context made and closed on demand). 2D: the four scenes of the ``mini`` split
(17 frames, 512²) with each engine's reference program; 3D: the first ``--scenes-3d`` 3D scenes
of the catalogue (75 frames, 512²) with the threejs reference program.

Between two renders the benchmark waits ``--gap`` seconds, as a run spends time scoring the clip
before the next render (a prepared page is made in that time); wall times are the render call
itself. CPU seconds are those of this process and all its children (Chromium, Playwright's
driver): per clip, from the first render of a block to the end of its last, background work
(pages prepared ahead, contexts closed) included, divided by the renders; and during the render
call alone (the critical path: on an idle machine the call takes about that long, less where
Chromium's processes overlap). Prints machine info (cores, CPU model, load average at start and end:
the machine may be shared), medians, the phase breakdown (`PageCapture.timings`), what the
pipeline pays per clip outside the renderer (H.264 encode and decode of the clip), peak RSS,
and whether frames are byte-identical across paths and repeats.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import tempfile
import time
from pathlib import Path

from machine import machine_info

_TICK = os.sysconf("SC_CLK_TCK")


def pss_bytes(pid: int) -> int:
    """Proportional set size (shared pages split between the processes sharing them): what a
    process tree holds without counting Chromium's shared pages once per process."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def process_kind(pid: int) -> str:
    """What a process of the tree is: python (this one), driver (Playwright's node), chromium's
    ``--type`` (renderer, gpu-process, utility, zygote), browser, or other (launchers)."""
    if pid == os.getpid():
        return "python"
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(
            errors="replace")
    except OSError:
        return "other"
    m = re.search(r"--type=([\w-]+)", cmd)
    if m:
        return m.group(1)
    exe = cmd.split(" ", 1)[0]
    if exe.endswith("/node") or exe == "node":
        return "driver"
    return "browser" if "chrom" in exe else "other"


class TreeCpu:
    """CPU seconds of this process and every descendant, counting processes that have ended
    (at their last sighting: sample often enough, e.g. after each render), in all and by kind
    of process (`process_kind`); and the peak memory of the tree (sum of PSS) at the samples."""

    def __init__(self) -> None:
        self._seen: dict[tuple[int, str], list] = {}  # (pid, start time) -> [kind, ticks]
        self.peak_pss_mib = 0.0

    def sample(self) -> float:
        from visphy_core.sandbox.chromium import descendants

        pss = 0
        for pid in [os.getpid(), *descendants(os.getpid())]:
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except (OSError, IndexError):
                continue
            key = (pid, fields[19])
            entry = self._seen.get(key)
            if entry is None or entry[0] in ("other", "browser"):  # forks are renamed later
                entry = self._seen[key] = [process_kind(pid), 0]
            entry[1] = int(fields[11]) + int(fields[12])
            pss += pss_bytes(pid)
        self.peak_pss_mib = max(self.peak_pss_mib, pss / 2**20)
        return sum(ticks for _, ticks in self._seen.values()) / _TICK

    def by_kind(self) -> dict[str, float]:
        """CPU seconds so far per kind of process."""
        out: dict[str, float] = {}
        for kind, ticks in self._seen.values():
            out[kind] = out.get(kind, 0.0) + ticks / _TICK
        return out


def median(xs) -> float | None:
    xs = list(xs)
    return round(statistics.median(xs), 3) if xs else None


def load_scenes(data_dir: Path, n_3d: int, pool) -> tuple[list, list]:
    """The ``mini`` 2D scenes and the first ``n_3d`` 3D scenes (built in a temp dir when the
    data dir does not hold them)."""
    from visphy_plugins.datasets.visphybench.build import build_dataset, write_scene
    from visphy_plugins.datasets.visphybench.catalogue import Entry
    from visphy_plugins.datasets.visphybench.loader import load_generated

    root = build_dataset(data_dir, split="mini", progress=False)
    scenes_2d = load_generated(root, split="mini")
    data = json.loads((root / "catalogue.json").read_text())
    ids_3d = [s["spec"]["scene_id"] for s in data["scenes"] if s["spec"]["dim"] == "3d"][:n_3d]
    built = [sid for sid in ids_3d if (root / "meta" / f"{sid}.json").is_file()]
    if len(built) == len(ids_3d):
        return scenes_2d, load_generated(root, scene_ids=ids_3d)
    tmp = Path(tempfile.mkdtemp(prefix="visphy-bench-3d-"))
    metas = []
    for s in data["scenes"]:
        if s["spec"]["scene_id"] in ids_3d:
            entry = Entry(spec=s["spec"], digest=s["digest"], attempts=1, rejected={})
            metas.append(write_scene(entry, tmp, pool))
    (tmp / "metadata.jsonl").write_text("".join(json.dumps(m) + "\n" for m in metas))
    return scenes_2d, load_generated(tmp)


def bench_group(engine, scenes, paths: dict, repeats: int, gap_s: float, cpu: TreeCpu) -> dict:
    """Render every scene ``repeats`` times with each path (blocks alternate between paths)."""
    from visphy_core.api.engine import RenderContract
    from visphy_core.infra.video import decode_video, encode_video, frame_digest
    from visphy_plugins.engines.browser_base import classify_capture

    programs = [(s, engine.program_from_spec(s), RenderContract.for_scene(s)) for s in scenes]
    out = {name: {"wall": [], "call_cpu": [], "classify": [], "cpu_s": 0.0, "renders": 0,
                  "phases": {},
                  "raw_frames": 0, "frames": 0, "cpu_by_kind": {}} for name in paths}
    digests: dict[tuple[str, str], list] = {}
    for name, pool in paths.items():  # untimed: starts the browser, prepares the first page
        engine.pool = pool
        engine.render(*programs[0][1:])
    for rep in range(repeats):
        for name in (paths if rep % 2 == 0 else list(paths)[::-1]):
            engine.pool = paths[name]
            row = out[name]
            time.sleep(gap_s)
            cpu0 = cpu.sample()
            kinds0 = cpu.by_kind()
            for scene, program, contract in programs:
                time.sleep(gap_s)
                c0 = cpu.sample()
                t0 = time.perf_counter()
                cap, _, _ = engine.capture_page(program, contract)
                t1 = time.perf_counter()
                row["call_cpu"].append(cpu.sample() - c0)
                result = classify_capture(cap, contract,
                                          expects_recording_call=engine.expects_recording_call)
                t2 = time.perf_counter()
                if not result.ok:
                    raise SystemExit(f"{engine.name} {scene.scene_id} ({name}): {result.error}")
                row["wall"].append(t1 - t0)
                row["classify"].append(t2 - t1)
                for phase, sec in cap.timings.items():
                    row["phases"].setdefault(phase, []).append(sec)
                row["raw_frames"] += cap.raw_frames
                row["frames"] += len(cap.frames)
                row["renders"] += 1
                digests.setdefault((scene.scene_id, name), []).append(
                    [frame_digest(f) for f in result.frames])
            time.sleep(gap_s)  # background work of the block's last render
            row["cpu_s"] += cpu.sample() - cpu0
            for kind, sec in cpu.by_kind().items():
                row["cpu_by_kind"][kind] = row["cpu_by_kind"].get(kind, 0.0) + sec - kinds0.get(
                    kind, 0.0)
    with tempfile.TemporaryDirectory() as tmp:  # what the pipeline pays outside the renderer
        frames = result.frames
        t0 = time.perf_counter()
        encode_video(frames, Path(tmp) / "clip.mp4", contract.fps)
        t1 = time.perf_counter()
        decode_video(Path(tmp) / "clip.mp4")
        t2 = time.perf_counter()
    first = list(paths)[0]
    identical_repeats = all(all(d == runs[0] for d in runs) for runs in digests.values())
    identical_paths = all(digests[(s.scene_id, name)][0] == digests[(s.scene_id, first)][0]
                          for s in scenes for name in paths)
    summary = {}
    for name, row in out.items():
        summary[name] = {
            "wall_s_median": median(row["wall"]),
            "wall_s_min": round(min(row["wall"]), 3), "wall_s_max": round(max(row["wall"]), 3),
            "cpu_s_per_clip": round(row["cpu_s"] / max(1, row["renders"]), 3),
            "cpu_s_during_call_median": median(row["call_cpu"]),
            "cpu_s_per_clip_by_process": {k: round(v / max(1, row["renders"]), 3)
                                          for k, v in sorted(row["cpu_by_kind"].items())
                                          if v > 0},
            "renders": row["renders"],
            "raw_frames_share": round(row["raw_frames"] / max(1, row["frames"]), 3),
            "phases_s_median": {k: median(v) for k, v in row["phases"].items()},
            "classify_s_median": median(row["classify"]),
        }
    return {"engine": engine.name, "dim": scenes[0].dim, "scenes": [s.scene_id for s in scenes],
            "frames": contract.n_frames, "size": f"{contract.width}x{contract.height}",
            "paths": summary, "identical_across_paths": identical_paths,
            "identical_across_repeats": identical_repeats,
            "pipeline_encode_s": round(t1 - t0, 3), "pipeline_decode_s": round(t2 - t1, 3)}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--data-dir", default="visphy-out/data")
    parser.add_argument("--engines", default="threejs,p5,svg")
    parser.add_argument("--scenes-3d", type=int, default=2)
    parser.add_argument("--paths", default="fast,png")
    parser.add_argument("--gap", type=float, default=0.5)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    from visphy_core.sandbox.browser import BrowserPool
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    report = {"machine_at_start": machine_info(), "repeats": args.repeats, "gap_s": args.gap}
    print(json.dumps(report["machine_at_start"]))
    known = {"fast": dict(), "png": dict(readback="png", prepare_pages=False)}
    paths = {name: BrowserPool(**known[name]) for name in args.paths.split(",")}
    cpu = TreeCpu()
    cpu.sample()
    engines = {"threejs": ThreeJsEngine, "p5": P5Engine, "svg": SvgEngine}
    scenes_2d, scenes_3d = load_scenes(Path(args.data_dir), args.scenes_3d,
                                       next(iter(paths.values())))
    groups = [(name, scenes_2d) for name in args.engines.split(",")]
    if "threejs" in args.engines.split(",") and scenes_3d:
        groups.append(("threejs", scenes_3d))
    report["groups"] = []
    for name, scenes in groups:
        engine = engines[name]()
        group = bench_group(engine, scenes, paths, args.repeats, args.gap, cpu)
        report["groups"].append(group)
        cells = "  ".join(f"{p}: {v['wall_s_median']:.3f} s wall, {v['cpu_s_per_clip']:.2f} s CPU"
                          for p, v in group["paths"].items())
        print(f"{name} {group['dim']} ({group['frames']} frames {group['size']}): {cells}; "
              f"identical across paths {group['identical_across_paths']}, repeats "
              f"{group['identical_across_repeats']}", flush=True)
    for pool in paths.values():
        pool.close()
    report["machine_at_end"] = machine_info()
    report["peak_pss_tree_mib"] = round(cpu.peak_pss_mib, 1)
    report["peak_rss_python_mib"] = round(
        resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(report, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
