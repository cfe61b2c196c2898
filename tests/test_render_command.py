"""``visphy render REPLY --engine E [--scene ID]``: rendering one reply needs only its scene (a
generated dataset builds that one scene, not its split) or, without ``--scene``, no scene at
all; the terminal gets a few lines (the video, its frames, the render's time, the scores it
has), never a line per empty score column."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from conftest import REPO, run_cli
from visphy_core.infra.video import decode_video
from visphy_plugins.testing.replies import HTML_PROGRAM, reply

pytestmark = pytest.mark.browser

FAST = ("metrics.names=[psnr,ssim]", "metrics.spec_track=false", "metrics.variance_norm=false")


def test_render_without_a_scene_renders_the_program_alone(tmp_path):
    home = tmp_path / "home"
    program = tmp_path / "ball.html"
    program.write_text(HTML_PROGRAM)  # a bare program: no fence, no analysis
    out = tmp_path / "out"
    proc = run_cli("render", str(program), "--engine", "threejs", "--frames", "3",
                   "--size", "64x48", "--fps", "4", "-o", str(out), home=home, check=False,
                   timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == f"ball: rendered {out / 'video.mp4'}"
    assert lines[1].startswith("3 frames 64x48 @ 4 fps · render ")
    assert any(line.startswith("not scored: no --scene") for line in lines)
    assert len(lines) <= 5 and "—" not in proc.stdout
    frames, info = decode_video(out / "video.mp4")
    assert frames.shape == (3, 48, 64, 3) and info.fps == 4
    for name in ("program.html", "render.log", "result.json"):
        assert (out / name).is_file(), name
    assert not (home / "data").exists()  # no dataset loaded, none built


def test_render_without_a_scene_reports_a_reply_without_a_program(tmp_path):
    text = tmp_path / "reply.txt"
    text.write_text("I would simulate this with a physics engine.\n")
    proc = run_cli("render", str(text), "--engine", "threejs", "-o", str(tmp_path / "out"),
                   home=tmp_path / "home", check=False, timeout=300)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert proc.stdout.splitlines()[0].startswith("reply: FAILED (no_code): ")


def test_render_of_one_generated_scene_builds_only_that_scene(visphy_home, tmp_path):
    """The default dataset (the generated benchmark's 209-scene split) with the mini split
    built: the render builds the one scene it names, and prints a few lines."""
    (root,) = [p for p in (visphy_home / "data").iterdir() if (p / "catalogue.json").is_file()]
    catalogue = json.loads((root / "catalogue.json").read_text())
    built = {p.stem for p in (root / "meta").glob("*.json")}
    dims = {s["spec"]["scene_id"]: s["spec"]["dim"] for s in catalogue["scenes"]}
    scene = next(sid for sid in catalogue["splits"]["sub"]
                 if sid not in built and dims[sid] == "2d")
    reply_file = tmp_path / "reply.txt"
    reply_file.write_text(reply("html"))
    out = tmp_path / "out"
    proc = run_cli("render", str(reply_file), "--engine", "threejs", "--scene", scene,
                   "-o", str(out), *FAST, "metrics.names=[psnr,ssim,spatiotemporal_iou_tol]",
                   home=visphy_home, check=False, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert {p.stem for p in (root / "meta").glob("*.json")} == built | {scene}
    lines = proc.stdout.splitlines()
    assert lines[0] == f"{scene}: rendered"
    assert lines[1].startswith(f"video: {out / 'video.mp4'} (17 frames 512x512 @ 5 fps) · "
                               "render ")
    assert len(lines) <= 10 and "—" not in proc.stdout, proc.stdout
    scores = json.loads((out / "scores.json").read_text())["scores"]
    for name in ("psnr", "ssim"):
        (line,) = [ln for ln in lines if ln.split()[:1] == [name]]
        assert float(line.split()[1]) == pytest.approx(scores[name], abs=1e-4)
    # the headline (a component is among the metrics) comes first, in the files as well
    (head,) = [ln for ln in lines if ln.startswith("physics_score: ")]
    assert lines.index(head) < min(i for i, ln in enumerate(lines) if ln.startswith("  "))
    row = json.loads((out / "result.json").read_text())
    assert float(head.split()[1]) == pytest.approx(scores["physics_score"], abs=1e-3)
    assert row["score_physics_score"] == scores["physics_score"]
    assert (out / "headline.json").is_file()
    assert lines[-1] == f"folder: {out}"


#: ``visphy`` in a child process whose catalogue simulator refuses to run.
NO_SIMULATION = ("import sys; from visphy_plugins.datasets.visphybench import build; "
                 "build.simulate_catalogue = lambda **_: sys.exit('simulated the catalogue'); "
                 "from visphy_core.cli.main import main; sys.exit(main(sys.argv[1:]))")


def test_render_of_one_scene_on_a_fresh_home_simulates_nothing(tmp_path):
    """A fresh home: the catalogue shipped with visphy is written (none is simulated) and the
    one scene named is the only one rendered."""
    home = tmp_path / "home"
    scene = "vpb3-s0-2d-t044-v01"
    reply_file = tmp_path / "reply.txt"
    reply_file.write_text(reply("html"))
    proc = subprocess.run([sys.executable, "-c", NO_SIMULATION, "render", str(reply_file),
                           "--engine", "threejs", "--scene", scene, "-o", str(tmp_path / "out"),
                           *FAST], cwd=REPO, env=dict(os.environ, VISPHY_HOME=str(home)),
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.splitlines()[0] == f"{scene}: rendered"
    (root,) = (home / "data").iterdir()
    assert [p.stem for p in (root / "meta").glob("*.json")] == [scene]
    assert [p.stem for p in (root / "videos").glob("*.mp4")] == [scene]
    assert len(json.loads((root / "catalogue.json").read_text())["scenes"]) == 209
