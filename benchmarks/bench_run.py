"""A whole run, timed: wall, CPU seconds and peak memory of the process tree, seconds per stage.

    .venv/bin/python benchmarks/bench_run.py [--dataset visphybench] [--scenes 8 | --every 26]
        [--model oracle] [--engine threejs] [--metrics default | --metric-names psnr,ssim]
        [--workers auto] [--home visphy-out] [--warm-cache] [--json out.json] [-- OVERRIDES…]

Runs ``python -m visphy_core`` as a user would (``tracking=none``, no progress bars), with the
data of ``--home`` and, unless ``--warm-cache``, an empty cache of its own (every reply, render
and score computed) and a scratch runs folder. ``--scenes N`` takes the split's first N scenes
(the generated benchmark lists its 2D scenes first); ``--every K`` every K-th scene, which keeps
the split's 2D/3D mix (what a timing per scene needs).

Prints machine info (cores, CPU model, load average at start and end: the machine may be
shared, and then wall figures are upper bounds while CPU seconds still count the work), then the
run's wall time, CPU seconds (user + system of the run and every process under it: Chromium,
Playwright's driver; sampled per process, see `TreeMemory`), CPU seconds per scene, peak RSS
(the sum over the process tree, sampled every 0.2 s, the run's Python process alone, and the
rest of the tree: Chromium's processes and Playwright's driver), the
seconds each stage took (summed over scenes: with several workers they overlap) and the render
wall time per clip from the rows.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from machine import machine

REPO = Path(__file__).resolve().parents[1]
_PAGE = os.sysconf("SC_PAGE_SIZE")


def _processes() -> tuple[dict[int, list[int]], dict[int, tuple[int, int]]]:
    """Every process's children, and its (start time, user + system clock ticks of its own),
    from one read of each ``/proc/<pid>/stat``."""
    tree: dict[int, list[int]] = {}
    cpu: dict[int, tuple[int, int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            pid = int(entry.name)
            cpu[pid] = (int(fields[19]), int(fields[11]) + int(fields[12]))
        except (OSError, IndexError, ValueError):
            continue
        tree.setdefault(int(fields[1]), []).append(pid)
    return tree, cpu


_TICKS = os.sysconf("SC_CLK_TCK")


def _rss(pid: int) -> int:
    try:
        return int((Path(f"/proc/{pid}/statm")).read_text().split()[1]) * _PAGE
    except (OSError, IndexError, ValueError):
        return 0


class TreeMemory:
    """Peak resident memory of a process and its descendants, and the CPU seconds they used,
    sampled on a thread.

    CPU: the last user + system time seen of every process of the tree, summed (`cpu_s`). The
    rusage of reaped children misses processes nobody waits for: Chromium's processes under
    bubblewrap are reaped inside their PID namespace, and their time never reaches the run's
    rusage (measured on a run with 2 workers: /proc/stat had both cores 97 % busy while the
    rusage counted 0.7 of them). The sampled sum misses only what a process used in its last
    ``every_s`` seconds."""

    def __init__(self, pid: int, every_s: float = 0.2):
        self.pid, self.every_s = pid, every_s
        self.peak_tree = self.peak_main = self.peak_others = 0
        self._ticks: dict[tuple[int, int], int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._stop.is_set():
            (tree, cpu), todo, total = _processes(), [self.pid], 0
            while todo:
                pid = todo.pop()
                total += _rss(pid)
                if pid in cpu:  # keyed with the start time: pids are reused
                    started, ticks = cpu[pid]
                    self._ticks[(pid, started)] = ticks
                todo += tree.get(pid, [])
            main = _rss(self.pid)
            self.peak_tree = max(self.peak_tree, total)
            self.peak_main = max(self.peak_main, main)
            self.peak_others = max(self.peak_others, total - main)
            self._stop.wait(self.every_s)

    @property
    def cpu_s(self) -> float:
        return sum(self._ticks.values()) / _TICKS

    def __enter__(self) -> "TreeMemory":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def split_ids(dataset: str, home: Path) -> list[str]:
    """The scene ids of a dataset config's split, in its order (the data must be built)."""
    sys.path.insert(0, str(REPO))
    from visphy_core.config.check import compose
    from visphy_core.execute.datasets import load_dataset

    cfg = compose([f"dataset={dataset}"])
    return [s.scene_id for s in load_dataset(cfg.dataset, home / "data", progress=False)]


def _manifest_wall(manifest: dict) -> float | None:
    """Seconds from the run's start (its dataset loaded, its engine up) to its end."""
    import datetime as dt

    try:
        return (dt.datetime.fromisoformat(manifest["ended"])
                - dt.datetime.fromisoformat(manifest["started"])).total_seconds()
    except (KeyError, TypeError, ValueError):
        return None


def run_once(*, dataset: str, scene_ids: list[str] | None, limit: int | None, model: str,
             engine: str, metrics: str | None, metric_names: str | None, workers: str,
             home: Path, warm_cache: bool, extra: list[str] = ()) -> dict:
    """One run as a subprocess; returns its figures (see the module docstring)."""
    scratch = Path(tempfile.mkdtemp(prefix="visphy-bench-run-"))
    args = [f"dataset={dataset}", f"model={model}", f"engine={engine}", "tracking=none",
            "run.progress=false", f"run.workers={workers}",
            f"paths.runs_dir={scratch / 'runs'}"]
    if not warm_cache:
        args.append(f"paths.cache_dir={scratch / 'cache'}")
    if metrics:
        args.append(f"metrics={metrics}")
    if metric_names:
        args.append(f"metrics.names=[{metric_names}]")
    if scene_ids is not None:
        args.append(f"dataset.scenes=[{','.join(scene_ids)}]")
    elif limit:
        args.append(f"dataset.limit={limit}")
    args += list(extra)
    env = dict(os.environ, VISPHY_HOME=str(home))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load_start = [round(x, 2) for x in os.getloadavg()]
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "visphy_core", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    with TreeMemory(proc.pid) as memory:
        out, err = proc.communicate()
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"the run failed ({proc.returncode}):\n{err[-3000:]}")
    (run_dir,) = (scratch / "runs").iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    rows = [json.loads(line) for line in (run_dir / "results.jsonl").read_text().splitlines()]
    renders = [r["render_wall_s"] for r in rows if r.get("render_wall_s") and
               not r.get("render_cached")]
    manifest = json.loads((run_dir / "manifest.json").read_text())
    reaped = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    cpu = max(memory.cpu_s, reaped)
    n = summary["n_scenes"]
    return {
        "scenes": n, "scenes_3d": sum(r["dim"] == "3d" for r in rows),
        "workers": manifest.get("workers"), "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1), "cpu_s_per_scene": round(cpu / n, 2) if n else None,
        "cpu_s_reaped_rusage": round(reaped, 1),
        "wall_s_per_scene": round(wall / n, 2) if n else None,
        "peak_rss_tree_gib": round(memory.peak_tree / 2**30, 2),
        "peak_rss_run_gib": round(memory.peak_main / 2**30, 2),
        "peak_rss_others_gib": round(memory.peak_others / 2**30, 2),
        "stages_s": {k.removesuffix("_s"): v["total"]
                     for k, v in (summary.get("stage_seconds") or {}).items() if v["total"]},
        "ground_truth": summary.get("ground_truth"),
        "run_wall_s": _manifest_wall(manifest),
        "before_run_s": (round(wall - _manifest_wall(manifest), 1)
                         if _manifest_wall(manifest) is not None else None),
        "render_wall_s_median": round(statistics.median(renders), 2) if renders else None,
        "model_success": summary["model_success"],
        "load_avg_start": load_start, "load_avg_end": [round(x, 2) for x in os.getloadavg()],
        "run_dir": str(run_dir), "args": args,
    }


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", default="visphybench")
    pick = parser.add_mutually_exclusive_group()
    pick.add_argument("--scenes", type=int, help="the split's first N scenes")
    pick.add_argument("--every", type=int, help="every K-th scene of the split")
    parser.add_argument("--model", default="oracle")
    parser.add_argument("--engine", default="threejs")
    parser.add_argument("--metrics", default="default", help="a metrics config (conf/metrics)")
    parser.add_argument("--metric-names", help="comma-separated metric names instead")
    parser.add_argument("--workers", default="auto")
    parser.add_argument("--home", default=os.environ.get("VISPHY_HOME", "visphy-out"))
    parser.add_argument("--warm-cache", action="store_true",
                        help="use the home's cache (default: an empty one)")
    parser.add_argument("--json", help="also write the figures here")
    args = parser.parse_args(argv)
    home = Path(args.home).resolve()
    ids = split_ids(args.dataset, home)[::args.every] if args.every else None
    info = machine()  # with the SIMD flags and the calibration figures
    figures = run_once(dataset=args.dataset, scene_ids=ids, limit=args.scenes,
                       model=args.model, engine=args.engine,
                       metrics=None if args.metric_names else args.metrics,
                       metric_names=args.metric_names, workers=args.workers, home=home,
                       warm_cache=args.warm_cache, extra=extra)
    print(f"machine: {info['usable_cores']} usable cores · {info['cpu']} · "
          f"{info['memory_gib']} GiB · load average at start {figures['load_avg_start']}, "
          f"at end {figures['load_avg_end']}")
    print(f"run: {figures['scenes']} scenes ({figures['scenes_3d']} 3D) · {args.model} × "
          f"{args.engine} · metrics {args.metric_names or args.metrics} · workers "
          f"{figures['workers']}")
    print(f"wall {figures['wall_s']} s ({figures['wall_s_per_scene']} s/scene) · CPU "
          f"{figures['cpu_s']} s ({figures['cpu_s_per_scene']} s/scene) · peak RSS "
          f"{figures['peak_rss_tree_gib']} GiB (tree), {figures['peak_rss_run_gib']} GiB (run), "
          f"{figures['peak_rss_others_gib']} GiB (the rest: Chromium, Playwright's driver)")
    print(f"SIMD {' '.join(info['simd'])} · calibration {json.dumps(info['calibration'])}")
    gt = figures["ground_truth"] or {}
    print(f"before the run (start-up, the dataset's scenes built): {figures['before_run_s']} s "
          f"· the run {figures['run_wall_s']} s, of it the ground-truth stage "
          f"{gt.get('wall_s')} s ({gt.get('computed_now')} scenes computed, "
          f"{gt.get('reused')} stored)")
    print("stages (s, summed over scenes): " + ", ".join(
        f"{k} {v}" for k, v in figures["stages_s"].items()))
    print(f"render wall per clip, median: {figures['render_wall_s_median']} s")
    if info["load_avg"][0] > info["usable_cores"] * 0.5:
        print("note: the machine was busy; wall times are upper bounds, CPU seconds count the "
              "work")
    if args.json:
        Path(args.json).write_text(json.dumps({"machine": info, **figures}, indent=1))


if __name__ == "__main__":
    main()
