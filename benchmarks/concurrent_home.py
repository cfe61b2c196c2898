"""Many visphy processes on one fresh home at once: every run completes with its rows, MLflow
holds one run per job, and the home works afterwards.

Starts the runs of `JOBS` (mixed models and engines, two with the same config) and one study
(a multirun over two models with the joblib launcher, ``hydra/launcher=local``) at the same
moment on one fresh ``VISPHY_HOME`` with the default sqlite MLflow store, waits for all, then
starts one more run (the first job's config again) and checks:

* every process exits 0 and prints no traceback;
* every run directory is finished, with exactly one row per selected scene;
* the MLflow store holds one FINISHED run per job and per study job, plus the study's parent
  run, none left RUNNING; the store is in WAL mode;
* the rows of the two runs with the same config, and of the run made afterwards, are equal.

Usage: ``python benchmarks/concurrent_home.py [--repeats 5] [--scenes 4] [--json out.json]``.
The first repeat builds the ``mini`` split into its fresh home (the shipped catalogue of all 209
scenes written there, as a new user's first run does); later repeats copy that build into their
fresh home, so each repeat after the first measures the runs, not the build.
tests/test_shared_home_runs.py runs a small version of the same check (`run_jobs`,
`check_home`) on every test run.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: The single runs started together (the first and the last share a config on purpose).
JOBS = (("model=oracle", "engine=threejs"), ("model=static", "engine=threejs"),
        ("model=oracle", "engine=p5"), ("model=static", "engine=p5"),
        ("model=oracle", "engine=svg"), ("model=flow_extrapolate", "engine=threejs"),
        ("model=oracle", "engine=threejs"))
#: The study started with them: a multirun in parallel worker processes.
STUDY = ("-m", "hydra/launcher=local", "model=oracle,static", "engine=svg")
#: What a row must agree on between two runs of one config (and every score).
COMPARED = ("scene_id", "model_success", "system_success", "fallback", "attempts",
            "failure_class", "first_failure_class", "frame_digests", "flags")


@dataclass
class Job:
    args: tuple[str, ...]
    proc: subprocess.Popen | None = None
    out: str = ""
    rc: int | None = None
    seconds: float = 0.0
    run_dirs: list[Path] = field(default_factory=list)


def start(home: Path, args: tuple[str, ...], common: tuple[str, ...]) -> Job:
    env = dict(os.environ, VISPHY_HOME=str(home))
    proc = subprocess.Popen([sys.executable, "-m", "visphy_core", *args, *common], cwd=REPO,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    return Job(args=args, proc=proc)


def finish(job: Job, started: float, timeout: float) -> Job:
    job.out, _ = job.proc.communicate(timeout=timeout)
    job.rc, job.seconds = job.proc.returncode, time.monotonic() - started
    job.run_dirs = [Path(p) for p in re.findall(r"^run directory: (.+)$", job.out, re.M)]
    return job


def run_jobs(home: Path, jobs, common: tuple[str, ...], timeout: float = 1800) -> list[Job]:
    """Start every job at once on ``home``; wait for all (each as `Job`)."""
    started = time.monotonic()
    running = [start(home, tuple(args), common) for args in jobs]
    return [finish(job, started, timeout) for job in running]


def comparable_rows(run_dir: Path) -> dict[str, dict]:
    rows = [json.loads(line) for line in (run_dir / "results.jsonl").read_text().splitlines()
            if line.strip()]
    return {r["scene_id"]: {**{k: r.get(k) for k in COMPARED},
                            **{k: v for k, v in r.items() if k.startswith("score_")}}
            for r in rows}


def mlflow_runs(home: Path) -> list[tuple[str, str]]:
    """(run name, status) of every run in the home's MLflow store."""
    with sqlite3.connect(home / "mlflow.db") as con:
        return con.execute("select name, status from runs").fetchall()


def check_home(home: Path, jobs: list[Job], n_scenes: int, expected_mlflow_runs: int
               ) -> list[str]:
    """What went wrong, one line each (empty: all good)."""
    problems = []
    for job in jobs:
        name = " ".join(job.args)
        if job.rc != 0 or "Traceback" in job.out:
            problems.append(f"{name}: exit {job.rc}: {job.out.strip().splitlines()[-1:]}")
    run_dirs = sorted(p for p in (home / "runs").iterdir() if p.is_dir())
    for run_dir in run_dirs:
        manifest = json.loads((run_dir / "manifest.json").read_text())
        rows = [json.loads(ln) for ln in (run_dir / "results.jsonl").read_text().splitlines()
                if ln.strip()]
        ids = [r["scene_id"] for r in rows]
        if manifest.get("status") != "finished":
            problems.append(f"{run_dir.name}: status {manifest.get('status')}")
        if sorted(ids) != sorted(manifest.get("scenes") or []) or len(ids) != n_scenes:
            problems.append(f"{run_dir.name}: rows {ids} for scenes {manifest.get('scenes')}")
    runs = mlflow_runs(home)
    finished = [n for n, status in runs if status == "FINISHED"]
    if len(finished) != expected_mlflow_runs or len(runs) != len(finished):
        problems.append(f"MLflow: {len(finished)} FINISHED of {len(runs)} runs, expected "
                        f"{expected_mlflow_runs}: {runs}")
    with sqlite3.connect(home / "mlflow.db") as con:
        mode = con.execute("pragma journal_mode").fetchone()[0]
    if mode.lower() != "wal":
        problems.append(f"MLflow store journal mode {mode}, not wal")
    return problems


def same_rows(a: Path, b: Path) -> str | None:
    """None when the two runs have equal rows, else one line."""
    ra, rb = comparable_rows(a), comparable_rows(b)
    return None if ra == rb else f"{a.name} and {b.name} differ: {ra} != {rb}"


def one_repeat(home: Path, data_from: Path | None, scenes: int) -> dict:
    if data_from is not None:  # the benchmark's build only: the ground truth is made anew
        for build in data_from.glob("visphybench-*"):
            shutil.copytree(build, home / "data" / build.name)
    common = ("dataset=mini", f"dataset.limit={scenes}")
    started = time.monotonic()
    jobs = run_jobs(home, [*JOBS, STUDY], common)
    together_s = time.monotonic() - started
    after = run_jobs(home, [JOBS[0]], common)
    expected = len(JOBS) + 1 + 2 + 1  # the singles, the one after, the study's two jobs + parent
    problems = check_home(home, [*jobs, *after], scenes, expected)
    firsts = [j.run_dirs[0] for j in jobs[:len(JOBS)] if j.run_dirs]
    same = [firsts[0], firsts[-1], *(after[0].run_dirs[:1])] if len(firsts) == len(JOBS) else []
    problems += [p for p in (same_rows(same[0], other) for other in same[1:]) if p]
    return {"together_s": round(together_s, 1), "after_s": round(after[0].seconds, 1),
            "per_job_s": {" ".join(j.args): round(j.seconds, 1) for j in jobs},
            "mlflow_runs": len(mlflow_runs(home)), "problems": problems,
            "outputs": {" ".join(j.args): j.out[-3000:] for j in [*jobs, *after]}
            if problems else {}}


def main() -> int:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from machine import machine

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scenes", type=int, default=4, help="scenes of mini per run (1-4)")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--data", type=Path, default=None,
                        help="a data folder holding a mini build to copy into every fresh home "
                             "(default: the first repeat builds it)")
    args = parser.parse_args()
    result = {"machine": machine(), "jobs": len(JOBS) + 1, "scenes": args.scenes,
              "repeats": []}
    with tempfile.TemporaryDirectory(prefix="visphy-concurrent-") as tmp:
        data = args.data
        for i in range(args.repeats):
            home = Path(tmp) / f"home{i}"
            home.mkdir()
            rep = one_repeat(home, data, args.scenes)
            data = data or home / "data"
            result["repeats"].append(rep)
            print(f"repeat {i + 1}/{args.repeats}: {rep['together_s']} s together, "
                  f"{rep['mlflow_runs']} MLflow runs, {len(rep['problems'])} problem(s)",
                  flush=True)
            for problem in rep["problems"]:
                print(f"  {problem}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    failed = sum(bool(r["problems"]) for r in result["repeats"])
    print(f"{args.repeats - failed}/{args.repeats} repeats without a problem")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
