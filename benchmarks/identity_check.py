"""Same run, two revisions: are the frames, scores and run directories identical?

A refactoring must not change what a run produces. This
script checks out two revisions side by side (``git worktree``), runs the main job on each
(``dataset=mini model=oracle engine=threejs metrics=default``, cold cache, tracking off) with
the same data directory, and compares the two run directories file by file:

* every file under ``scenes/`` byte for byte (clips, frames, replies, per-scene scores), except
  the files that record wall-clock times;
* ``results.jsonl`` / ``results.parquet`` row by row and ``summary.json`` / ``manifest.json``
  key by key, without what differs between any two runs of one revision: wall-clock seconds,
  timestamps, the run directory's own name and paths, cache hit counts, versions of the code;
* the same set of files on both sides.

Each revision runs with the entry points its own ``pyproject.toml`` declares (a throwaway
``visphy`` distribution placed first on the path), so a revision that moved its modules runs
as it would when installed. Exit status 0 when identical; otherwise every difference is
printed.

    .venv/bin/python benchmarks/identity_check.py --before 8e685d5 [--after HEAD] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: The main job, tracking off; anchors computed in each run (no shared ground-truth store).
JOB = ["dataset=mini", "model=oracle", "engine=threejs", "metrics=default", "tracking=none",
       "run.progress=false", "paths.ground_truth_dir=null"]
#: Row fields and JSON keys that differ between two runs of one revision (wall-clock times,
#: where the run lives, cache statistics, versions).
VOLATILE_KEYS = {
    "model_latency_s", "render_wall_s", "reference_render_wall_s", "scoring_wall_s",
    "judge_wall_s", "wall_s", "cpu_s", "stage_seconds", "started_at", "finished_at",
    "updated_at", "at",
    "run_dir", "cache", "visphy_version", "git", "git_commit", "command", "argv", "pid",
    "host", "hostname", "elapsed_s", "duration_s", "seconds", "python", "platform", "usage",
    "render_cached", "response_cached", "renders_done", "model_calls", "mlflow", "tracking",
    "infra_retries", "latency_s", "started", "ended", "stamp",
}
#: Keys of a file that name the code rather than what it produced: the manifest lists the plugin
#: entry points loaded, which a restructuring renames (reported, not counted as a difference).
STRUCTURAL = {"manifest.json": {"plugins"}}
#: Files whose lines are written in the order calls finish (two workers): compared sorted.
UNORDERED = {"calls.jsonl"}
#: Per-scene files that hold wall-clock times (compared as JSON without `VOLATILE_KEYS`).
TIMED_FILES = {"timings.json", "render_meta.json", "normalisation.json"}


def worktree(rev: str, where: Path) -> Path:
    subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(where)],
                   capture_output=True)
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "-f", "--detach", str(where), rev],
                   check=True, capture_output=True)
    for name, target in (("visphy_plugins", "plugins"), ("visphy_conf", "conf")):
        link = where / name
        if not link.exists():
            link.symlink_to(target)
    return where


def entry_point_shim(tree: Path, where: Path) -> Path:
    """A ``visphy`` distribution holding only ``tree``'s entry points: first on the path, it
    shadows the installed one, so ``tree`` loads its plugins from its own module names."""
    project = tomllib.loads((tree / "pyproject.toml").read_text())["project"]
    dist = where / "visphy-0.0.0.dist-info"
    shutil.rmtree(dist, ignore_errors=True)
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: visphy\nVersion: 0.0.0\n")
    lines = []
    groups = dict(project.get("entry-points", {}))
    if project.get("scripts"):
        groups["console_scripts"] = project["scripts"]
    for group, entries in groups.items():
        lines.append(f"[{group}]")
        lines += [f"{name} = {value}" for name, value in entries.items()]
        lines.append("")
    (dist / "entry_points.txt").write_text("\n".join(lines))
    return where


def run_job(tree: Path, shim: Path, home: Path, data: Path) -> Path:
    env = {**os.environ, "VISPHY_HOME": str(home),
           "PYTHONPATH": os.pathsep.join([str(shim), str(tree)])}
    cmd = [sys.executable, "-m", "visphy_core", *JOB, f"paths.data_dir={data}"]
    out = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{tree}: the run failed ({out.returncode}):\n{out.stdout[-3000:]}\n"
                         f"{out.stderr[-3000:]}")
    runs = sorted((home / "runs").iterdir())
    if len(runs) != 1:
        raise SystemExit(f"{home / 'runs'}: expected one run directory, found {len(runs)}")
    return runs[0]


def scrub(value, homes: tuple[str, ...]):
    """``value`` without `VOLATILE_KEYS` (recursively), its paths under either home made
    relative, and floats compared exactly (NaN equal to NaN)."""
    if isinstance(value, dict):
        return {k: scrub(v, homes) for k, v in value.items() if k not in VOLATILE_KEYS}
    if isinstance(value, list):
        return [scrub(v, homes) for v in value]
    if isinstance(value, str):
        for home in homes:
            value = value.replace(home, "<HOME>")
        return value
    if isinstance(value, float) and math.isnan(value):
        return "NaN"
    return value


def _json(path: Path):
    if path.suffix == ".jsonl":
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return json.loads(path.read_text())


def compare(a: Path, b: Path, homes: tuple[str, ...]) -> list[str]:
    skip = {".lock"}
    files_a = {p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.name not in skip}
    files_b = {p.relative_to(b) for p in b.rglob("*") if p.is_file() and p.name not in skip}
    diffs = [f"only in the first run: {p}" for p in sorted(files_a - files_b)]
    diffs += [f"only in the second run: {p}" for p in sorted(files_b - files_a)]
    for rel in sorted(files_a & files_b):
        pa, pb = a / rel, b / rel
        if rel.suffix in (".json", ".jsonl"):
            ja, jb = scrub(_json(pa), homes), scrub(_json(pb), homes)
            for key in STRUCTURAL.get(str(rel), ()):
                if isinstance(ja, dict) and isinstance(jb, dict) and ja.get(key) != jb.get(key):
                    print(f"note: {rel}: {key} differs (the code's own names)")
                    ja.pop(key, None)
                    jb.pop(key, None)
            if rel.name in UNORDERED:
                ja, jb = (sorted(x, key=lambda r: json.dumps(r, sort_keys=True)) for x in (ja, jb))
            if ja != jb:
                diffs.append(f"{rel}: differs (volatile keys excluded)")
        elif rel.suffix == ".parquet":
            import pandas as pd

            ta = pd.read_parquet(pa).drop(columns=list(VOLATILE_KEYS), errors="ignore")
            tb = pd.read_parquet(pb).drop(columns=list(VOLATILE_KEYS), errors="ignore")
            if not ta.equals(tb):
                diffs.append(f"{rel}: rows differ (volatile columns excluded)")
        elif rel.suffix in (".yaml", ".html", ".txt", ".md"):
            ta, tb = pa.read_text(), pb.read_text()
            for home in homes:
                ta, tb = ta.replace(home, "<HOME>"), tb.replace(home, "<HOME>")
            ta, tb = ta.replace(a.name, "<RUN>"), tb.replace(b.name, "<RUN>")
            if ta != tb and rel.name not in ("index.html",):
                diffs.append(f"{rel}: text differs")
        elif pa.read_bytes() != pb.read_bytes():
            diffs.append(f"{rel}: bytes differ")
    return diffs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="the first revision (a commit or branch)")
    ap.add_argument("--after", default="HEAD", help="the second revision (default HEAD)")
    ap.add_argument("--keep", type=Path, help="keep the two homes here (default: a temp dir)")
    args = ap.parse_args()
    base = args.keep or Path(tempfile.mkdtemp(prefix="visphy-identity-"))
    base.mkdir(parents=True, exist_ok=True)
    data = base / "data"   # built once, by the first run; the ground-truth store is off
    trees = []
    try:
        run_dirs = []
        for label, rev in (("before", args.before), ("after", args.after)):
            tree = worktree(rev, base / f"tree-{label}")
            trees.append(tree)
            shim = entry_point_shim(tree, base / f"shim-{label}")
            home = base / f"home-{label}"
            shutil.rmtree(home, ignore_errors=True)
            print(f"{label}: {rev} → {home}", flush=True)
            run_dirs.append(run_job(tree, shim, home, data))
        diffs = compare(*run_dirs, homes=(str(base / "home-before"), str(base / "home-after"),
                                          str(base / "tree-before"), str(base / "tree-after")))
    finally:
        for tree in trees:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)],
                           capture_output=True)
        if args.keep is None:
            shutil.rmtree(base, ignore_errors=True)
    if diffs:
        print(f"{len(diffs)} difference(s):")
        print("\n".join(f"  {d}" for d in diffs))
        return 1
    print(f"identical: {args.before} and {args.after} give the same frames, scores and run "
          "directory on the mini split")
    return 0


if __name__ == "__main__":
    sys.exit(main())
