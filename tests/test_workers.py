"""Scenes side by side (`run.workers`, visphy_core/execute/scheduler.py): the same rows, frames and
scores
with one worker and with two; the scheduler's gates (slots, the render lane in scene order, the
call lane of ``run.prefetch=0``), rows handed back in scene order, cancelling and draining; the
progress lines' in-flight counts; and ``run.workers`` itself."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest
from rich.console import Console

from conftest import REPO, run_cli
from visphy_core.execute.console import StageProgress, stage_progress
from visphy_core.execute.scheduler import (
    SceneCancelled,
    SceneScheduler,
    StageGates,
    resolve_workers,
    usable_cores,
)
from visphy_core.infra.events import StageEvents
from visphy_core.results.summary import STAGE_FIELDS

# --------------------------------------------------------------------------- one vs two workers

#: Row fields that may differ between two runs of the same command: timings and cache flags.
VARYING = (*STAGE_FIELDS, "render_cached", "response_cached")
#: Per-scene files whose bytes must not depend on the number of workers.
SCENE_FILES = ("scores.json", "frames_meta.json", "normalisation.json", "metric_details.json",
               "spec_validation.json", "render.log", "render.attempt2.log")
#: fsim rounds differently with another torch thread count (the reason torch is pinned; two
#: pairs per pairing show it); the spec track and normalisation render reference clips inside
#: the score stage.
METRICS = ("metrics.names=[psnr,ssim,fsim]", "+metrics.max_pairs.fsim=2",
           "metrics.spec_track=true", "metrics.variance_norm=true")


def _scripted_run(home: Path, workers: int, script: dict) -> Path:
    env = dict(os.environ, VISPHY_HOME=str(home), VISPHY_COUNTER=str(home / "calls.txt"),
               VISPHY_SCRIPT=json.dumps(script))
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "tests"), env.get("PYTHONPATH", "")])
    proc = subprocess.run(
        [sys.executable, str(REPO / "tests" / "scripted_cli.py"), "model=oracle",
         "model.name=counting", "engine=threejs", "dataset=mini", "dataset.limit=3",
         "tracking=none", "run.progress=false", "run.cache=false", f"run.workers={workers}",
         *METRICS], cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run_dir,) = (home / "runs").iterdir()
    return run_dir


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory, mini_root, mini_scenes):
    """The same three scenes (one ok, one repaired, one fallback) with run.workers=1 and 2,
    each in its own home and cache (nothing of one run is read by the other)."""
    import shutil

    ids = [s.scene_id for s in mini_scenes[:3]]
    script = {ids[1]: ["broken", "oracle"], ids[2]: ["broken", "no_code"]}
    runs = {}
    for workers in (1, 2):
        home = tmp_path_factory.mktemp(f"workers{workers}")
        shutil.copytree(mini_root, home / "data" / mini_root.name)
        runs[workers] = _scripted_run(home, workers, script)
    return runs


def _rows(run_dir: Path) -> list[dict]:
    rows = [json.loads(line) for line in (run_dir / "results.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in VARYING} for r in rows]


@pytest.mark.browser
def test_one_and_two_workers_give_the_same_rows_frames_and_scores(two_runs):
    one, two = two_runs[1], two_runs[2]
    manifests = [json.loads((d / "manifest.json").read_text()) for d in (one, two)]
    assert [m["workers"]["workers"] for m in manifests] == [1, 2]
    rows = _rows(one)
    assert rows == _rows(two)  # every field, in the same (scene) order
    outcomes = [(r["model_success"], r["attempts"], r["fallback"]) for r in rows]
    assert outcomes == [(True, 1, False), (True, 2, False), (False, 2, True)]
    assert all(json.loads(r["frame_digests"]) for r in rows if r["model_success"])
    assert all(r["score_fsim"] is not None and r["score_norm.fsim"] is not None for r in rows)
    assert rows[0]["score_spec.fsim"] is not None  # the spec track ran
    tables = [pd.read_parquet(d / "results.parquet").drop(columns=list(VARYING))
              for d in (one, two)]
    pd.testing.assert_frame_equal(*tables)
    summaries = [json.loads((d / "summary.json").read_text()) for d in (one, two)]
    assert summaries[0]["metrics"] == summaries[1]["metrics"]
    compared = 0
    for scene in (one / "scenes").iterdir():
        for name in SCENE_FILES:
            if (scene / name).is_file():
                assert (scene / name).read_bytes() == (
                    two / "scenes" / scene.name / name).read_bytes(), f"{scene.name}/{name}"
                compared += 1
        for clip in ("video.mp4", "spec_video.mp4", "twin_video.mp4"):
            if (scene / clip).is_file():
                assert (scene / clip).read_bytes() == (two / "scenes" / scene.name / clip
                                                       ).read_bytes(), f"{scene.name}/{clip}"
    assert compared >= 3 * 4


@pytest.mark.browser
def test_sigint_with_scenes_in_flight_closes_the_run_and_exits_130(tmp_path, mini_root):
    """Two workers, model calls one second apart (run.prefetch=0: one call at a time): the
    signal lands while scenes render, score and wait; the run waits for them to stop, writes a
    partial summary and exits 130 (not an abort from a thread left inside torch)."""
    import shutil
    import signal

    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    env = dict(os.environ, VISPHY_HOME=str(home), VISPHY_COUNTER=str(home / "calls.txt"),
               VISPHY_MODEL_DELAY="1.0")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "tests"), env.get("PYTHONPATH", "")])
    proc = subprocess.Popen(
        [sys.executable, str(REPO / "tests" / "scripted_cli.py"), "model=oracle",
         "model.name=counting", "dataset=mini", "tracking=none", "run.progress=false",
         "run.workers=2", "run.prefetch=0", "metrics.names=[psnr,ssim]",
         "metrics.spec_track=false", "metrics.variance_norm=false"],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 300
        rows = home / "runs"
        while not any(p.stat().st_size for p in rows.glob("*/results.jsonl")):
            assert proc.poll() is None and time.monotonic() < deadline, "no row in time"
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out[-3000:]
    assert "Traceback" not in out and "terminate called" not in out
    (run_dir,) = rows.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "interrupted" and 1 <= summary["n_scenes"] < 4
    lines = (run_dir / "results.jsonl").read_text().splitlines()
    assert len(lines) == summary["n_scenes"]
    calls = (home / "calls.txt").read_text().splitlines()
    assert [c.split()[0] for c in calls] == sorted(c.split()[0] for c in calls)  # in order


# --------------------------------------------------------------------------- the gates

class Recorder(StageEvents):
    """Stage events as the progress would see them: who is in which stage, at most how many."""

    def __init__(self):
        self.lock = threading.Lock()
        self.now: dict[str, set] = {}
        self.most: dict[str, int] = {}
        self.entered: dict[str, list] = {}

    def begin(self, stage, scene_id):
        with self.lock:
            self.now.setdefault(stage, set()).add(scene_id)
            self.most[stage] = max(self.most.get(stage, 0), len(self.now[stage]))
            self.entered.setdefault(stage, []).append(scene_id)

    def end(self, stage, scene_id):
        with self.lock:
            self.now[stage].discard(scene_id)

    def scene_finished(self, scene_id):  # what a scene that raised left open
        with self.lock:
            for now in self.now.values():
                now.discard(scene_id)


def _scene(gates: StageGates, delays: dict, fail: str | None = None):
    """A scene's life through the gates: generate, render, score (with a nested reference
    render), judge; ``delays[id]`` seconds of work in each stage."""
    def process(scene_id: str) -> str:
        try:
            return life(scene_id)
        finally:
            gates.scene_finished(scene_id)

    def life(scene_id: str) -> str:
        wait = delays.get(scene_id, 0.01)
        with gates.stage("generate", scene_id):
            time.sleep(wait / 2)
        with gates.stage("render", scene_id):
            time.sleep(wait)
        with gates.stage("score", scene_id):
            time.sleep(wait)
            if scene_id == fail:
                raise ValueError(f"{scene_id} broke")
            with gates.stage("render", scene_id):  # the twin, inside the score stage
                time.sleep(0.005)
        with gates.stage("judge", scene_id):
            time.sleep(wait / 2)
        return scene_id.upper()
    return process


def test_scenes_overlap_within_their_gates_and_come_back_in_order():
    events = Recorder()
    gates = StageGates(events, workers=2)
    ids = [f"s{i}" for i in range(8)]
    delays = {"s0": 0.3, "s1": 0.05, "s2": 0.2, "s5": 0.15}  # finish out of order
    scheduler = SceneScheduler(ids, key=str, process=_scene(gates, delays, fail="s3"),
                               gates=gates)
    out = list(scheduler.results())
    assert [i for i, _ in out] == ids
    assert [o for _, o in out if isinstance(o, str)] == [i.upper() for i in ids if i != "s3"]
    (error,) = [o for _, o in out if not isinstance(o, str)]
    assert isinstance(error, ValueError) and "s3 broke" in str(error)
    assert events.most["score"] == 2       # the workers' slots
    assert events.most["render"] == 1      # one render at a time
    assert events.most["generate"] > 1     # model calls are not gated
    first_renders = list(dict.fromkeys(events.entered["render"]))
    assert first_renders == ids            # first renders in scene order


def test_serial_calls_keep_model_calls_one_at_a_time_in_scene_order():
    events = Recorder()
    gates = StageGates(events, workers=3, serial_calls=True)
    ids = [f"s{i}" for i in range(6)]
    scheduler = SceneScheduler(ids, key=str, process=_scene(gates, {"s0": 0.2}), gates=gates)
    assert [o for _, o in scheduler.results()] == [i.upper() for i in ids]
    assert events.most["generate"] == 1 and events.entered["generate"] == ids


def test_outside_a_worker_the_gates_only_report():
    events = Recorder()
    gates = StageGates(events, workers=1)
    with gates.stage("render", "x"), gates.stage("score", "x"), gates.stage("render", "x"):
        pass  # no slot, no lane: the same thread may nest freely
    assert events.entered == {"render": ["x", "x"], "score": ["x"]}


def test_cancel_abandons_scenes_in_flight_and_drain_finishes_them():
    gates = StageGates(Recorder(), workers=1)
    started = threading.Event()
    finished: list[str] = []

    def slow(scene_id: str) -> str:
        with gates.stage("score", scene_id):
            started.set()
            time.sleep(0.3)
        with gates.stage("judge", scene_id):
            finished.append(scene_id)
        return scene_id

    scheduler = SceneScheduler([f"s{i}" for i in range(10)], key=str, process=slow,
                               gates=gates)
    results = scheduler.results()
    assert next(results) == ("s0", "s0")
    scheduler.drain()
    taken = list(results)  # those already taken finish and come back; nothing new starts
    assert len(taken) < 9 and [o for _, o in taken] == [i for i, _ in taken]

    gates = StageGates(Recorder(), workers=1)
    started.clear()
    finished.clear()
    scheduler = SceneScheduler(["a", "b", "c"], key=str, process=slow, gates=gates)
    results = scheduler.results()
    threading.Thread(target=lambda: (started.wait(5), scheduler.cancel()), daemon=True).start()
    assert list(results) == []
    time.sleep(0.5)
    assert finished == []  # the scene in its score stage never reached its judges
    with pytest.raises(SceneCancelled):
        gates.check()


# --------------------------------------------------------------------------- progress

def test_stage_lines_show_how_many_scenes_are_in_each_stage():
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=140, color_system=None)
    with stage_progress(3, ["generate", "render", "score"], out=console) as progress:
        progress.begin("score", "scene_a")
        progress.begin("score", "scene_b")
        progress.progress.refresh()
        assert progress.in_flight("score") == ["scene_a", "scene_b"]
        assert "2 in flight" in out.getvalue() and "scene_a +1" in out.getvalue()
        for scene in ("scene_a", "scene_b", "scene_c"):
            progress.end("score", scene)
            progress.scene_finished(scene)
    assert progress.most_in_flight["score"] == 2 and progress.skipped["render"] == 3
    assert " summed over scenes: generate 3/3 (3 skipped) 0.0 s, " in progress.final_line()


def test_progress_counts_are_right_under_many_threads():
    progress = StageProgress(200, ["score"], live=False)

    def scene(i: int) -> None:
        progress.begin("score", f"s{i}")
        progress.end("score", f"s{i}")
        progress.scene_finished(f"s{i}")

    threads = [threading.Thread(target=scene, args=(i,)) for i in range(200)]
    [t.start() for t in threads]
    [t.join() for t in threads]
    assert len(progress.done["score"]) == 200 and progress.skipped["score"] == 0
    assert progress.in_flight("score") == []


# --------------------------------------------------------------------------- run.workers

def test_workers_auto_follows_the_cores_and_numbers_pass_through():
    assert 1 <= resolve_workers("auto") <= usable_cores()
    assert resolve_workers(3) == 3 and resolve_workers("2") == 2


@pytest.mark.parametrize("value", ["0", "two"])
def test_a_bad_worker_count_is_one_line_before_any_work(tmp_path, value):
    proc = run_cli("dataset=tiny", "model=static", "tracking=none", f"run.workers={value}",
                   home=tmp_path / "home", check=False)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "run.workers" in lines[0] and "auto" in lines[0], proc.stderr
    assert not (tmp_path / "home" / "runs").exists()


def test_the_worker_count_does_not_change_the_config_hash():
    from visphy_core.config.check import compose
    from visphy_core.results.run_dir import config_hash

    hashes = {config_hash(compose([f"run.workers={w}"])) for w in ("auto", "1", "4")}
    assert len(hashes) == 1
