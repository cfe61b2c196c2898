"""Progress per stage and what a run prints at its end: one line per stage (live bars on a
terminal, else one closing line), then the summary table, the HTML report's path and the exact
``mlflow ui`` command of the run's tracking store."""

from __future__ import annotations

import io
import os
import pty
import re
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from rich.console import Console

from conftest import REPO, run_cli
from visphy_core.execute.console import StageProgress, stage_progress


def test_stage_lines_count_scenes_and_skips():
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=120, color_system=None)
    with stage_progress(2, ["generate", "render", "score", "judge"], out=console) as progress:
        for scene in ("scene_a", "scene_b"):
            for stage in ("generate", "render", "score", "judge"):
                if scene == "scene_b" and stage == "render":
                    continue  # e.g. a reply with no code: nothing to render
                progress.begin(stage, scene)
                progress.end(stage, scene)
            progress.begin("generate", scene)  # a repair call: time adds up, no double count
            progress.end("generate", scene)
            progress.scene_finished(scene)
    text = out.getvalue()
    final = text.split("\r")[-1] if "\r" in text else text
    for stage in ("generate", "render", "score", "judge"):
        assert re.search(rf"{stage}\s.*2/2", final), final
    assert progress.done["render"] == {"scene_a", "scene_b"} and progress.skipped["render"] == 1
    assert progress.skipped["generate"] == 0
    line = progress.final_line()
    assert line.startswith("stages: wall ") and " · summed over scenes: generate 2/2 " in line
    assert "render 2/2 (1 skipped) " in line


def test_an_unstarted_stage_is_not_counted_twice():
    progress = StageProgress(1, ["score"], live=False)
    progress.end("score", "x")
    progress.scene_finished("x")
    assert progress.done["score"] == {"x"} and progress.skipped["score"] == 0
    progress.end("render", "x")  # a stage this run does not have: ignored
    assert "render" not in progress.final_line()


def test_a_run_ends_with_the_stage_line_report_and_mlflow_command(tmp_path):
    home = tmp_path / "home"
    proc = run_cli("dataset=tiny", "model=static", home=home)
    stages = [ln for ln in proc.stderr.splitlines() if ln.startswith("stages: ")]
    assert len(stages) == 1, proc.stderr
    assert re.match(r"stages: wall [\d.]+ s · summed over scenes: generate 3/3 [\d.]+ s, "
                    r"score 3/3 [\d.]+ s$", stages[0]), stages[0]
    assert "render" not in stages[0]  # a video model renders nothing
    lines = proc.stdout.splitlines()
    (run_dir,) = (home / "runs").iterdir()
    tail = [ln for ln in lines if ln.startswith(("run directory: ", "report: ", "MLflow: "))]
    assert [t.split(":", 1)[0] for t in tail] == ["run directory", "report", "MLflow"]
    report = Path(tail[1].removeprefix("report: "))
    assert report == run_dir / "report" / "index.html" and report.is_file()
    command = tail[2].removeprefix("MLflow: ")
    uri = f"sqlite:///{(home / 'mlflow.db').resolve()}"
    executable, rest = command.split(" ", 1)
    assert rest == f"ui --backend-store-uri {uri}"
    # it works as printed, the venv not activated: its mlflow by full path unless on the path
    bare = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PATH")}
    bare["PATH"] = "/usr/bin:/bin"
    exe = shutil.which(executable, path=bare["PATH"]) or executable
    check = subprocess.run([exe, "ui", "--help"], env=bare, capture_output=True, text=True,
                           timeout=120)
    assert check.returncode == 0 and "--backend-store-uri" in check.stdout, check.stderr
    from mlflow.tracking import MlflowClient

    runs = MlflowClient(tracking_uri=uri).search_runs(
        [e.experiment_id for e in MlflowClient(tracking_uri=uri).search_experiments()],
        filter_string=f"tags.`visphy.run_dir` = '{run_dir}'")
    assert len(runs) == 1 and runs[0].info.status == "FINISHED"
    assert runs[0].info.run_name == "static · threejs · tiny:sub"   # the runs list's name


def test_live_bars_on_a_terminal_and_nothing_without_tracking(tmp_path):
    """stdout on a pseudo-terminal: the stages are drawn (on stderr) instead of the closing
    line; with tracking=none no MLflow line."""
    home = tmp_path / "home"
    master, slave = pty.openpty()
    env = dict(os.environ, VISPHY_HOME=str(home))
    shown = bytearray()

    def read_terminal() -> None:  # drained as it is written, so the child never blocks
        while True:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                return
            if not chunk:
                return
            shown.extend(chunk)

    reader = threading.Thread(target=read_terminal, daemon=True)
    reader.start()
    proc = subprocess.run([sys.executable, "-m", "visphy_core", "dataset=tiny", "model=static",
                           "tracking=none", "metrics.names=[psnr]", "metrics.spec_track=false",
                           "metrics.variance_norm=false"], cwd=REPO, env=env, stdout=slave,
                          stderr=subprocess.PIPE, text=True, timeout=300)
    os.close(slave)
    reader.join(timeout=10)
    os.close(master)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "stages: " not in proc.stderr
    assert re.search(r"generate\s.*3/3", proc.stderr) and re.search(r"score\s.*3/3", proc.stderr)
    assert b"report: " in shown and b"MLflow: " not in shown


class FakeClock:
    """A clock the test moves by hand: no sleeping."""

    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _bar_of(text: str, stage: str) -> str:
    """The last drawing of ``stage``'s line on a live console's output."""
    plain = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "\n", text).replace("\r", "\n")
    return [ln for ln in plain.split("\n") if ln.strip().startswith(stage)][-1]


def test_a_stage_bar_never_goes_back_after_its_total():
    """A scene back in a stage it is done with (its score stage's reference renders enter
    ``render`` again) adds its time but is no new work: the finished bar stays "done", never
    "1 in flight"."""
    clock = FakeClock()
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=120, color_system=None)
    progress = StageProgress(2, ["render", "score"], live=True, out=console, clock=clock)
    with progress.progress:
        for scene in ("a", "b"):
            progress.begin("render", scene)
            clock.now += 2
            progress.end("render", scene)
        assert progress.progress.tasks[progress.tasks["render"]].description == "done"
        progress.begin("score", "b")
        progress.begin("render", "b")  # the spec track's reference render, during score
        clock.now += 3
        assert progress.in_flight("render") == []
        assert progress.progress.tasks[progress.tasks["render"]].description == "done"
        assert progress.spent_now("render") == 7.0  # its time still adds up
        progress.end("render", "b")
        progress.end("score", "b")
    task = progress.progress.tasks[progress.tasks["render"]]
    assert task.completed == 2 and task.description == "done"
    assert progress.spent["render"] == 7.0
    assert "in flight" not in _bar_of(out.getvalue(), "render")


def test_a_running_stage_shows_its_time_advancing():
    """The seconds column counts the scenes in a stage now, not only those that left it."""
    clock = FakeClock()
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=120, color_system=None)
    progress = StageProgress(1, ["score"], live=True, out=console, clock=clock)
    with progress.progress:
        progress.begin("score", "a")
        clock.now += 61.5
        assert progress.spent_now("score") == 61.5
        progress.progress.refresh()
        assert "61.5s" in _bar_of(out.getvalue(), "score")
        clock.now += 1
        progress.end("score", "a")
    assert progress.spent["score"] == 62.5 and progress.spent_now("score") == 62.5


def _long_summary():
    """A summary with long scene ids, many metrics under every pairing, a negative zero and a
    tiny value, as `print_summary` takes it."""
    from visphy_core.results.row import SceneResult

    long_names = [f"a_rather_long_metric_name_number_{i}_moving_dis" for i in range(5)]
    names = ["psnr", "ssim", "track_pos_err", *long_names]
    metric = {"unavailable": None, "direction": "lower", "n_model_success": 2,
              "mean_model_success": 0.123456, "mean_with_fallbacks": 0.5, "n_with_fallbacks": 2}
    metrics = {"physics_score": dict(metric, direction="higher", mean_model_success=-0.0)}
    for name in names:
        metrics[name] = dict(metric)
        metrics[f"{name}.aligned"] = dict(metric)
        metrics[f"paper.{name}"] = dict(metric)
        metrics[f"spec.{name}"] = dict(metric)
        metrics[f"norm.{name}"] = dict(metric, mean_model_success=-6.1)
    info = {n: {"family": "motion" if "moving" in n else "pixel"} for n in names}
    ids = [f"vpb3-s0-2d-t00{i}-v00-with-an-unusually-long-scene-identifier-{i}" for i in (1, 2)]
    scores = {n: 0.1 + i for i, n in enumerate(names)} | {"physics_score": -1e-9,
                                                          "psnr": 4.701e-05}
    results = [SceneResult(scene_id=i, dim="2d", difficulty=None, model_success=True,
                           attempts=1, render_wall_s=1.25, scores=scores) for i in ids]
    summary = {"model": "a_model_with_a_long_name", "engine": "threejs", "dataset": "mini",
               "n_scenes": 2, "metrics": metrics, "metric_info": info,
               "headline": {"metric": "physics_score", "mean": -0.0, "ci": [-0.0, 0.5], "n": 2},
               "model_success": 2, "system_success": 2, "fallbacks": 0, "repaired": 0,
               "cache": {"render": {"hits": 0, "misses": 2}},
               "stage_seconds": {"render_wall_s": {"total": 2.5}, "scoring_wall_s":
                                 {"total": 187.7}},
               "run_dir": "/tmp/run"}
    return summary, results, ids, long_names


@pytest.mark.parametrize("columns", [80, 100])
def test_the_default_summary_fits_the_terminal(capsys, monkeypatch, columns):
    """At 80 and 100 columns (and in a log) every line of the default summary fits; scene ids
    lose only the prefix they share; the headline has its interval; the time line says which
    seconds are wall time and which are summed over scenes; no negative zero."""
    from visphy_core.execute.console import print_summary

    monkeypatch.setenv("COLUMNS", str(columns))
    summary, results, ids, long_names = _long_summary()
    print_summary(summary, results, wall_s=99.3)
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert all(len(ln.rstrip()) <= columns for ln in lines), \
        [ln for ln in lines if len(ln.rstrip()) > columns]
    assert "…" not in text and "-0.0000" not in text and "-0 " not in text
    assert "(scene ids without the prefix they share: vpb3-s0-2d-)" in text
    assert "95% bootstrap interval [0, 0.5]" in text and "4.701e-05" in text
    assert "time: wall 99.3 s · summed over scenes: render 2.5 s, score 187.7 s" in \
        " ".join(text.split())
    assert "run.summary=full" in text and "norm" in text
    assert "aligned" not in text  # the pairings are in the full summary


def test_the_full_summary_explains_its_columns(capsys, monkeypatch):
    """``run.summary=full``: every metric under every pairing, each column's meaning under the
    table (norm included); in a log nothing is cut."""
    from visphy_core.execute.console import print_summary

    monkeypatch.delenv("COLUMNS", raising=False)
    summary, results, ids, long_names = _long_summary()
    print_summary(summary, results, mode="full")
    text = capsys.readouterr().out
    assert "…" not in text and "-0.0000" not in text
    for name in long_names:
        assert f"{name} ↓" in text
    for view in ("visphy", "aligned", "paper", "spec", "norm"):
        assert f"  {view}: " in text
    assert "0 = the first frame held still" in text and "-6.1" in text


def test_one_scored_scene_says_why_it_has_no_interval(capsys):
    from visphy_core.execute.console import print_summary

    summary, results, _, _ = _long_summary()
    summary["headline"] = {"metric": "physics_score", "mean": 0.25, "ci": None, "n": 1}
    print_summary(summary, results[:1])
    text = " ".join(capsys.readouterr().out.split())
    assert "headline physics_score ↑ 0.25 over 1 scored scene (no interval: a bootstrap " \
           "needs at least 2 scored scenes)" in text
    assert "bootstrap interval [" not in text


def test_plain_lines_are_paced_per_key_with_a_heartbeat():
    """In a log: a key's lines at most every `EVERY` seconds (a forced one always shows), and
    a heartbeat once nothing was written for `QUIET` seconds, not before."""
    from visphy_core.infra.progress import EVERY, QUIET, PlainLines

    clock, out = FakeClock(), io.StringIO()
    lines = PlainLines(heartbeat=lambda: "still working", out=out, clock=clock)
    assert lines.emit("render", "render 1/4")
    clock.now += EVERY / 2
    assert not lines.emit("render", "render 2/4")   # too soon for this key
    assert lines.emit("score", "score 1/4")          # another key has its own pace
    assert not lines.emit("score", "score 2/4")
    assert lines.emit("render", "render 4/4 done", force=True)
    clock.now += EVERY
    assert lines.tick()                              # the held-back score line, once due
    clock.now += QUIET - 1
    assert not lines.tick()
    clock.now += 1
    assert lines.tick()
    assert not lines.tick()                          # the heartbeat also resets the silence
    assert out.getvalue().splitlines() == ["render 1/4", "score 1/4", "render 4/4 done",
                                           "score 2/4", "still working"]


def test_rates_are_read_without_exponents():
    from visphy_core.infra.progress import rate_and_eta

    assert rate_and_eta(970, 970, 1.0) == "970/s"
    assert rate_and_eta(5, 10, 2.0) == "2.5/s · ETA 2 s"
    assert rate_and_eta(1, 10, 10.0) == "6/min · ETA 1 min 30 s"
    assert rate_and_eta(9, 100, 30.0) == "18/min · ETA 5 min 03 s"


def test_stage_lines_for_a_log_have_count_rate_and_eta():
    clock = FakeClock()
    progress = StageProgress(4, ["render", "score"], live=False, clock=clock, plain=True)
    out = io.StringIO()
    progress.lines.out = out
    progress.begin("render", "a")
    clock.now += 10
    progress.end("render", "a")
    progress.begin("render", "b")
    line = progress.stage_line("render")
    assert line.startswith("render 1/4 · 1 in flight · 6/min · ETA 30 s · 10 s elapsed"), line
    assert "\x1b" not in out.getvalue() and out.getvalue().startswith("render 0/4 · 1 in flight")
    assert progress.heartbeat_line() == ("still working, 10 s elapsed: render 1/4 (1 in "
                                         "flight), score 0/4")


def test_a_run_in_a_log_reports_progress_while_it_goes(visphy_home):
    """stdout and stderr pipes: a progress line soon after the stages start and then no
    silence longer than the heartbeat allows (with slack for a loaded machine), no terminal
    codes, the closing stage line at the end."""
    import time

    env = dict(os.environ, VISPHY_HOME=str(visphy_home), PYTHONUNBUFFERED="1")
    env.pop("COLUMNS", None)
    from conftest import FAST_METRICS

    proc = subprocess.Popen([sys.executable, "-m", "visphy_core", "model=oracle",
                             "dataset=mini", "dataset.limit=1", "tracking=none",
                             *FAST_METRICS], cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    stamped = []
    for line in proc.stdout:
        stamped.append((time.monotonic(), line.rstrip("\n")))
    assert proc.wait(timeout=600) == 0, "\n".join(ln for _, ln in stamped)[-3000:]
    text = "\n".join(ln for _, ln in stamped)
    assert "\x1b[" not in text
    starts = [t for t, ln in stamped if ln.startswith("1 scene to run · stages ")]
    ends = [t for t, ln in stamped if ln.startswith("stages: wall ")]
    assert len(starts) == 1 and len(ends) == 1, text
    during = [t for t, ln in stamped if starts[0] <= t <= ends[0]]
    gaps = [b - a for a, b in zip(during, during[1:])]
    assert max(gaps, default=0) < 20, (gaps, text)
    assert re.search(r"^(generate|render|score) 1/1 · done", text, re.M), text


def test_a_study_says_which_job_starts_and_when_it_should_end(tmp_path):
    import datetime as dt

    from visphy_core.results import study_records as records
    from visphy_core.study.callback import count_jobs, study_progress_line

    assert count_jobs({"model": "oracle,static", "engine": "threejs,p5,manim"}) == 6
    for num, status in enumerate((records.COMPLETED, records.FAILED, records.RUNNING)):
        records.write_job(tmp_path / str(num), num=num, sweep_dir=str(tmp_path), status=status)
    study = {"name": "leaderboard", "n_jobs": 6, "started": "2026-01-01T10:00:00"}
    line = study_progress_line(tmp_path, study, 2, "model=static",
                               now=dt.datetime(2026, 1, 1, 10, 4, 0))
    assert line == ("study leaderboard: job 3/6 (model=static) · 1 done, 1 failed · "
                    "4 min 00 s elapsed · ETA 8 min 00 s")
