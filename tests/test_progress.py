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
