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
    assert line.startswith("stages: generate 2/2 (") and "render 2/2 (" in line
    assert "1 skipped" in line.split("render", 1)[1].split("·")[0]


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
    assert re.match(r"stages: generate 3/3 \([\d.]+ s\) · score 3/3 \([\d.]+ s\) · [\d.]+ s in "
                    r"all$", stages[0]), stages[0]
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


def test_the_summary_is_never_cut_when_stdout_is_not_a_terminal(capsys):
    """A pipe or a log file gets the tables whole: every header and value in full, however many
    and however long the columns are (rich alone would cut them at 80 columns with "…")."""
    from visphy_core.execute.console import print_summary
    from visphy_core.results.row import SceneResult

    long_names = [f"a_rather_long_metric_name_number_{i}_moving_dis" for i in range(5)]
    metric = {"unavailable": None, "direction": "lower", "n_model_success": 1,
              "mean_model_success": 0.123456, "mean_with_fallbacks": 0.5, "n_with_fallbacks": 2}
    metrics = {name: dict(metric) for name in long_names}
    metrics.update({f"{long_names[0]}.aligned": dict(metric), f"paper.{long_names[1]}":
                    dict(metric), f"spec.{long_names[2]}": dict(metric)})
    scene_id = "vpb3-s0-2d-t001-v00-with-an-unusually-long-scene-identifier"
    results = [SceneResult(scene_id=scene_id, dim="2d", difficulty=None, model_success=True,
                           attempts=1, render_wall_s=1.25,
                           scores={n: 0.1 + i for i, n in enumerate(long_names)})]
    summary = {"model": "a_model_with_a_long_name", "engine": "threejs", "dataset": "mini",
               "n_scenes": 1, "metrics": metrics, "headline": {}, "model_success": 1,
               "system_success": 1, "fallbacks": 0, "repaired": 0,
               "cache": {"render": {"hits": 0, "misses": 1}}, "run_dir": "/tmp/" + "x" * 150}
    print_summary(summary, results)
    text = capsys.readouterr().out
    assert "…" not in text
    for i, name in enumerate(long_names):
        assert f"{name} ↓" in text  # a header of both tables, whole on one line
        assert f"{0.1 + i:.4f}" in text
    for column in ("aligned", "paper", "spec", "with fallbacks"):
        assert column in text
    assert scene_id in text and "0.5000 (n=2)" in text and "1.25s" in text
    assert f"run directory: /tmp/{'x' * 150}" in text
