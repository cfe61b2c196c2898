"""A run killed mid-run resumes on rerun: identical rows to an uninterrupted run, no
duplicate or missing row, no repeated model call (but the one a SIGKILL may catch between its
reply and the cache write: the reply is recorded in the ledger, fsynced, first, so a paid call is
never missing from the costs); SIGTERM/SIGINT close the run with a partial summary and exit
143/130."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from conftest import FAST_METRICS, REPO

#: the first test's setup makes the uninterrupted reference run (95 s with its own test on a
#: loaded 2-core dev box, the mini build included); each test makes two or three runs
pytestmark = [pytest.mark.browser, pytest.mark.timeout(600)]

ARGS = ["model=oracle", "model.name=counting", "engine=threejs", "dataset=mini",
        "dataset.limit=4", "tracking=none", "run.progress=false", *FAST_METRICS]
#: The interrupted runs: one worker, so rows come one by one and the kill lands mid-run; the
#: rerun (run.workers=auto) resumes it all the same (the worker count is not in the config hash).
PACED = [*ARGS, "run.workers=1"]
COMPARED = ("scene_id", "model_success", "system_success", "fallback", "attempts",
            "failure_class", "first_failure_class", "frame_digests", "flags")


@pytest.fixture(scope="module")
def script(mini_scenes) -> dict:
    ids = [s.scene_id for s in mini_scenes[:4]]
    # mixed outcomes: ok, repaired after a runtime error, fallback after two failures, ok
    return {ids[1]: ["broken", "oracle"], ids[2]: ["broken", "no_code"]}


def _env(home: Path, script: dict) -> dict:
    env = dict(os.environ, VISPHY_HOME=str(home), VISPHY_COUNTER=str(home / "model_calls.txt"),
               VISPHY_SCRIPT=json.dumps(script), VISPHY_MODEL_DELAY="0.2")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "tests"), env.get("PYTHONPATH", "")])
    return env


def _start(home: Path, script: dict, args: list[str] = ARGS) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(REPO / "tests" / "scripted_cli.py"), *args],
                            cwd=REPO, env=_env(home, script), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def _run(home: Path, script: dict, args: list[str] = ARGS) -> subprocess.CompletedProcess:
    proc = _start(home, script, args)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-4000:]
    return subprocess.CompletedProcess(proc.args, proc.returncode, out)


def _rows_done(home: Path) -> int:
    return sum(len([ln for ln in p.read_text().splitlines() if ln.endswith("}")])
               for p in (home / "runs").glob("*/results.jsonl")) if (home / "runs").is_dir() else 0


def _wait_for_rows(proc: subprocess.Popen, home: Path, n: int, timeout: float = 300) -> None:
    end = time.monotonic() + timeout
    while _rows_done(home) < n:
        assert proc.poll() is None, f"exited {proc.returncode} before {n} row(s)"
        assert time.monotonic() < end, "no row in time"
        time.sleep(0.02)


def _calls(home: Path) -> list[str]:
    path = home / "model_calls.txt"
    return path.read_text().splitlines() if path.is_file() else []


def _the_run(home: Path) -> Path:
    (run_dir,) = (home / "runs").iterdir()  # a resumed run reuses its directory
    return run_dir


def _comparable(run_dir: Path) -> dict[str, dict]:
    lines = (run_dir / "results.jsonl").read_text().splitlines()
    rows = [json.loads(line) for line in lines]
    ids = [r["scene_id"] for r in rows]
    assert len(ids) == len(set(ids)), f"duplicate rows: {ids}"
    table = pd.read_parquet(run_dir / "results.parquet")
    assert sorted(table["scene_id"]) == sorted(ids)
    out = {}
    for r in rows:
        scores = {k: v for k, v in r.items() if k.startswith("score_")}
        out[r["scene_id"]] = {**{k: r[k] for k in COMPARED}, **scores}
    return out


@pytest.fixture(scope="module")
def reference(tmp_path_factory, mini_root, script):
    import shutil

    home = tmp_path_factory.mktemp("uninterrupted")
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    _run(home, script)
    run_dir = _the_run(home)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["n_scenes"] == 4
    rows = _comparable(run_dir)
    classes = {r["failure_class"] for r in rows.values()}
    assert {None, "no_code"} <= classes and any(r["attempts"] == 2 for r in rows.values())
    return rows, _calls(home), summary


def _fresh_home(tmp_path, mini_root) -> Path:
    import shutil

    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


#: Where the SIGKILL lands: after this many rows are written, and this many seconds later
#: (fixed, so that a failure reproduces). The first point is right after a row is committed;
#: the second is mid-way into the third scene, the one `script` makes fail twice (two model
#: calls paced 0.2 s each by VISPHY_MODEL_DELAY, a failed render, a fallback): well before the
#: last row, even on a fast machine.
KILL_POINTS = [(1, 0.0), (2, 0.3)]


@pytest.mark.parametrize("rows_first, pause_s", KILL_POINTS,
                         ids=[f"after{r}rows+{p}s" for r, p in KILL_POINTS])
def test_sigkill_mid_run_then_rerun_gives_identical_results(
        tmp_path, mini_root, script, reference, rows_first, pause_s):
    ref_rows, ref_calls, ref_summary = reference
    home = _fresh_home(tmp_path, mini_root)
    point = f"kill after {rows_first} row(s) + {pause_s} s"
    proc = _start(home, script, PACED)
    try:
        _wait_for_rows(proc, home, rows_first)
        time.sleep(pause_s)
        done_at_kill = _rows_done(home)
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    assert rows_first <= done_at_kill < 4, f"{point}: killed after {done_at_kill} rows"
    run_dir = _the_run(home)
    assert json.loads((run_dir / "manifest.json").read_text())["status"] == "running"
    at_kill = _calls(home)
    calls_before = len(at_kill)

    out = _run(home, script).stdout
    assert "resuming" in out
    rows = _comparable(_the_run(home))
    assert rows == ref_rows, point
    calls = _calls(home)
    # no call is repeated, but for one the kill may catch between the model's reply (counted)
    # and the cache write a few ms later: then the last call counted before the kill, and only
    # it, is made again
    repeated = len(calls) - len(ref_calls)
    assert repeated in (0, 1), f"{point}: {calls} vs {ref_calls}"
    if repeated:
        assert at_kill and calls.count(at_kill[-1]) == 2 and \
            sorted(calls) == sorted(ref_calls + [at_kill[-1]]), (point, at_kill, calls)
    assert len(calls) >= calls_before
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["resumed_rows"] >= 1
    assert summary["metrics"] == ref_summary["metrics"]
    assert summary["failures"] == ref_summary["failures"]


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_writes_a_partial_summary_and_the_rerun_resumes(
        tmp_path, mini_root, script, reference, sig, code):
    ref_rows, ref_calls, _ = reference
    home = _fresh_home(tmp_path, mini_root)
    proc = _start(home, script, PACED)
    try:
        _wait_for_rows(proc, home, 1)
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, out[-3000:]
    assert "Traceback" not in out and "rerun the same command to resume" in out
    run_dir = _the_run(home)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["interrupted_by"] == sig.name
    assert 1 <= summary["n_scenes"] < 4 and summary["n_selected"] == 4
    assert json.loads((run_dir / "manifest.json").read_text())["status"] == "interrupted"
    assert len(pd.read_parquet(run_dir / "results.parquet")) == summary["n_scenes"]

    # SIGINT: the same command finds the run (run.resume=auto); SIGTERM: named by its path
    _run(home, script, PACED if sig == signal.SIGINT else [*PACED, f"run.resume={run_dir}"])
    assert _comparable(_the_run(home)) == ref_rows
    assert len(_calls(home)) == len(ref_calls)
    assert json.loads((run_dir / "summary.json").read_text())["status"] == "finished"


def test_run_resume_names_the_run_or_refuses_in_one_line(tmp_path):
    from visphy_core.infra.errors import ConfigError
    from visphy_core.results.run_dir import RunLock, claim_run_dir

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    manifest = run_dir / "manifest.json"
    for status, chash, match in (("finished", "h", "that run is finished"),
                                 ("interrupted", "other", "config differs")):
        manifest.write_text(json.dumps({"status": status, "config_hash": chash}))
        with pytest.raises(ConfigError, match=match):
            claim_run_dir(run_dir, "h")
    manifest.write_text(json.dumps({"status": "interrupted", "config_hash": "h"}))
    held = RunLock(run_dir)
    assert held.acquire()
    with pytest.raises(ConfigError, match="another process is working in it"):
        claim_run_dir(run_dir, "h")
    held.release()
    claimed, lock = claim_run_dir(run_dir, "h")
    assert claimed == run_dir.resolve()
    lock.release()
    with pytest.raises(ConfigError, match="not a run directory"):
        claim_run_dir(tmp_path / "nowhere", "h")


def test_a_finished_run_is_not_resumed(tmp_path, mini_root, script, reference):
    """Rerunning after a finished run starts a new run directory (every row recomputed from the
    cache, no model call repeated)."""
    _, ref_calls, _ = reference
    home = _fresh_home(tmp_path, mini_root)
    _run(home, script)
    _run(home, script)
    assert len(list((home / "runs").iterdir())) == 2
    assert len(_calls(home)) == len(ref_calls)


def test_a_resumed_run_closes_the_killed_mlflow_run(tmp_path, mini_root, script):
    import sqlite3

    args = [a for a in ARGS if a != "tracking=none"] + ["dataset.limit=2"]
    args.remove("dataset.limit=4")
    home = _fresh_home(tmp_path, mini_root)
    proc = _start(home, script, args)
    try:
        _wait_for_rows(proc, home, 1)
        proc.kill()
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    with sqlite3.connect(home / "mlflow.db") as con:
        assert [s for (s,) in con.execute("select status from runs")] == ["RUNNING"]
    _run(home, script, args)
    with sqlite3.connect(home / "mlflow.db") as con:
        statuses = dict(con.execute("select run_uuid, status from runs").fetchall())
        tags = dict(con.execute("select run_uuid, value from tags "
                                "where key = 'visphy.resumed_from'").fetchall())
    assert sorted(statuses.values()) == ["FINISHED", "KILLED"]
    ((new, old),) = tags.items()
    assert statuses[new] == "FINISHED" and statuses[old] == "KILLED"


def _private_tmpfs_run(home: Path, script: dict, runs: Path, size: str, args: list[str],
                       keep: Path) -> subprocess.CompletedProcess:
    """The run with ``paths.runs_dir`` on a tmpfs of ``size`` in a private mount namespace
    (``unshare -m``: the mount is gone with the process); the run folders are copied to
    ``keep`` before it goes."""
    cli = " ".join(map(shlex.quote, [sys.executable, str(REPO / "tests" / "scripted_cli.py"),
                                     *args, f"paths.runs_dir={runs}"]))
    shell = (f"mount -t tmpfs -o size={size} tmpfs {runs} || exit 99; "
             f"{cli}; rc=$?; cp -a {runs}/. {keep}/; exit $rc")
    return subprocess.run(["unshare", "-m", "sh", "-c", shell], cwd=REPO,
                          env=_env(home, script), capture_output=True, text=True, timeout=600)


def _blocks(path: Path) -> int:
    return sum(p.lstat().st_blocks * 512 for p in [path, *path.rglob("*")])


def _room_for_1_5_scenes(reference) -> int:
    """KB for the run's first files, its first scene and half its second, as the uninterrupted
    run wrote them: the disk fills in the middle of the second scene."""
    run_dir = Path(reference[2]["run_dir"])
    scenes = sorted((run_dir / "scenes").iterdir())
    first = sum(_blocks(run_dir / name) for name in ("config.yaml", "manifest.json"))
    return (first + _blocks(scenes[0]) + _blocks(scenes[1]) // 2 + 8192) // 1024


def test_a_full_disk_is_one_line_and_the_rerun_resumes(tmp_path, mini_root, script, reference):
    """The runs folder on a file system that fills in the second scene: the run stops at a scene
    boundary with one ``error: disk full writing <path> (... free there, about ... needed)``
    line and exit status 74, its rows kept and its manifest not finished; with space again, the
    same command resumes
    to the uninterrupted run's rows, no model call repeated."""
    if shutil.which("unshare") is None or os.geteuid() != 0:
        pytest.skip("needs root and util-linux unshare to mount a small tmpfs privately")
    ref_rows, ref_calls, _ = reference
    home = _fresh_home(tmp_path, mini_root)
    runs, keep = home / "runs", tmp_path / "kept"
    runs.mkdir()
    keep.mkdir()
    full = _private_tmpfs_run(home, script, runs, f"{_room_for_1_5_scenes(reference)}k", PACED,
                              keep)
    assert full.returncode == 74, (full.returncode, full.stderr[-3000:])
    errors = [ln for ln in full.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in full.stderr, full.stderr[-3000:]
    assert errors[0].startswith("error: disk full writing ") and " needed" in errors[0]
    assert "rerun the same command to resume" in errors[0]
    (run_dir,) = keep.iterdir()
    assert json.loads((run_dir / "manifest.json").read_text())["status"] != "finished"
    kept = [json.loads(ln) for ln in (run_dir / "results.jsonl").read_text().splitlines()
            if ln.endswith("}")]
    assert len(kept) < 4

    shutil.copytree(keep, runs, dirs_exist_ok=True)  # space again: the same command
    done = subprocess.run([sys.executable, str(REPO / "tests" / "scripted_cli.py"), *PACED],
                          cwd=REPO, env=_env(home, script), capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "resuming" in done.stderr
    assert _comparable(_the_run(home)) == ref_rows
    assert len(_calls(home)) == len(ref_calls)
