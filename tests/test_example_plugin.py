"""The example third-party plugin (examples/visphy-plugin-example): one module per plugin kind,
pip-installed, each kind exercised through the real registry, then all of them in one real run.

It is installed into a private target folder, never into the shared .venv: other test files run
at the same time (xdist workers) and must not discover, or lose halfway, a plugin they did not
ask for. CLI subprocesses see it on their PYTHONPATH (entry points are found there as in
site-packages: importlib.metadata reads every sys.path entry's *.dist-info). In this process the
registry is built from the installed distribution's own entry points (`example_registry`), so
the process-wide registry other tests use never holds them."""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import subprocess
import sys
from importlib.metadata import distributions
from pathlib import Path

import numpy as np
import pluggy
import pytest
from omegaconf import OmegaConf

from conftest import REPO, run_cli
from visphy_core.api import hookspecs
from visphy_core.api.registry import build_registry

EXAMPLE = REPO / "examples" / "visphy-plugin-example"
ENTRY_POINTS = ("example_configs", "example_dataset", "example_engine", "example_judge",
                "example_lifecycle", "example_metric", "example_model", "example_physics")


@pytest.fixture(scope="module")
def installed_example(tmp_path_factory) -> Path:
    """The folder the example plugin is pip-installed into."""
    base = tmp_path_factory.mktemp("example-plugin")
    source = base / "src"  # a copy: building in place would leave build/ files in the repo
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    target = base / "site"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run(pip + ["install", "--no-deps", "--no-build-isolation", "--target",
                          str(target), str(source)], check=True, capture_output=True)
    return target


@pytest.fixture(scope="module")
def example_env(installed_example) -> dict:
    """The env that puts the installed example plugin on a subprocess's path."""
    path = os.pathsep.join(p for p in (str(installed_example), os.environ.get("PYTHONPATH"))
                           if p)
    return {"PYTHONPATH": path}


@pytest.fixture(scope="module")
def example_registry(installed_example):
    """A registry of the installed distribution's entry points alone."""
    (dist,) = distributions(path=[str(installed_example)])
    assert dist.metadata["Name"] == "visphy-plugin-example"
    pm = pluggy.PluginManager("visphy")
    pm.add_hookspecs(hookspecs)
    sys.path.insert(0, str(installed_example))
    try:
        for ep in dist.entry_points.select(group="visphy"):
            pm.register(ep.load(), name=ep.name)
    finally:
        sys.path.remove(str(installed_example))
    return pm, build_registry(pm)


@pytest.fixture(scope="module")
def squares(example_registry, tmp_path_factory):
    """The example dataset's scenes (written on first use)."""
    dataset = example_registry[1].get("datasets", "example_squares")()
    return dataset.load(OmegaConf.create({"scenes": None}), tmp_path_factory.mktemp("data"))


def boxes_reply(ay: float, green: int) -> str:
    """A reply for the example engine: a square falling from rest like an example scene's."""
    box = {"x": 19, "y": 2, "vx": 0, "vy": 0, "ax": 0, "ay": ay, "w": 10, "h": 10,
           "rgb": [200, green, 40]}
    return f"The square falls from rest.\n\n```boxes\n{json.dumps({'boxes': [box]})}\n```\n"


def test_every_module_is_a_plugin_of_its_own(example_registry):
    pm, registry = example_registry
    assert sorted(name for name, _ in pm.list_name_plugin()) == list(ENTRY_POINTS)
    assert list(registry.models) == ["example_still"]
    assert list(registry.engines) == ["example_boxes"]
    assert list(registry.metrics) == ["example_mae"]
    assert list(registry.judges) == ["example_pixels"]
    assert list(registry.datasets) == ["example_squares"]
    assert list(registry.physics) == ["example_euler"]
    assert sorted(registry.configs) == ["engine/example_boxes", "judge/example_pixels",
                                        "model/example_still"]
    lifecycle = pm.get_plugin("example_lifecycle")
    assert {c.name for c in pm.get_hookcallers(lifecycle)} == {
        "visphy_run_start", "visphy_scene_done", "visphy_run_end"}


def test_model_answers_with_a_program_holding_the_first_key_frame(example_registry, squares):
    from visphy_core.api.media import png_bytes
    from visphy_core.api.model import ImageInput, ModelRequest, OutputContract

    model = example_registry[1].get("models", "example_still")(None)
    first = png_bytes(squares[0].key_frame(1))
    request = ModelRequest("s", "prompt", [ImageInput("frame_01", first)], None, "threejs",
                           "html", OutputContract(6, 12, 48, 48))
    text = model.generate(request).text
    assert "```html\n<!DOCTYPE html>" in text and 'width="48" height="48"' in text


def test_engine_renders_a_program_and_reports_a_bad_one(example_registry, squares):
    from visphy_core.api.engine import FailureClass, Program, ProgramRejected, RenderContract

    engine = example_registry[1].get("engines", "example_boxes")(None)
    contract = RenderContract.for_scene(squares[1])
    program = engine.extract(boxes_reply(90, 40))
    engine.validate(program)
    result = engine.render(program, contract)
    assert result.ok and result.frames.shape == (12, 48, 48, 3)
    truth = squares[1].reference_frames().astype(float)
    assert np.abs(result.frames - truth).mean() < 8  # the same fall, up to the codec

    bad = Program("boxes", '{"boxes": [{"x": 1}]}')
    with pytest.raises(ProgramRejected) as rejected:
        engine.validate(bad)
    assert rejected.value.failure is FailureClass.SYNTAX_ERROR
    assert engine.render(bad, contract).failure is FailureClass.SYNTAX_ERROR
    with pytest.raises(ProgramRejected) as wrong:
        engine.extract("```html\n<html></html>\n```")
    assert wrong.value.failure is FailureClass.WRONG_LANGUAGE


def test_metric_is_zero_on_identical_frames(example_registry):
    metric = example_registry[1].get("metrics", "example_mae")
    a = np.zeros((2, 4, 4, 3), np.uint8)
    b = a.copy()
    b[1] = 255
    assert metric.pair_values(a, b).tolist() == [0.0, 255.0]
    assert metric.describe()["direction"] == "lower" and metric.unavailable_reason() is None


def test_judge_gives_a_verdict(example_registry, squares, tmp_path):
    from visphy_core.api.judge import JudgeInput
    from visphy_core.api.media import encode_video

    cfg = OmegaConf.create({"name": "example_pixels", "scale": 32.0, "reduce": "mean"})
    judge = example_registry[1].get("judges", "example_pixels")(cfg)
    still = np.repeat(squares[2].reference_frames()[:1], 12, axis=0)
    encode_video(still, tmp_path / "still.mp4", 6)

    def verdict(generated: Path):
        return asyncio.run(judge.ajudge(JudgeInput("s", "2d", squares[2].video_path, generated,
                                                   6, 12)))

    same, moved = verdict(squares[2].video_path), verdict(tmp_path / "still.mp4")
    assert same.valid and same.score == 10.0
    assert moved.valid and 1.0 <= moved.score < 10.0
    missing = verdict(tmp_path / "absent.mp4")
    assert not missing.valid and missing.score is None and "cannot read" in missing.error


def test_dataset_lists_its_scenes_and_checks_the_ids(example_registry, squares):
    from visphy_core.api.errors import ConfigError

    assert [s.scene_id for s in squares] == ["task20000_000", "task20001_000", "task20002_000"]
    assert squares[0].check_inputs((1, 10)).shape == (12, 48, 48, 3)
    dataset = example_registry[1].get("datasets", "example_squares")()
    dataset.check(OmegaConf.create({"dataset": {"scenes": ["task20000_000"]}}))
    with pytest.raises(ConfigError, match="nope not in example_squares"):
        dataset.check(OmegaConf.create({"dataset": {"scenes": ["nope"]}}))


def test_dataset_returns_only_the_scenes_named(example_registry, tmp_path):
    dataset = example_registry[1].get("datasets", "example_squares")()
    scenes = dataset.load(OmegaConf.create({"scenes": ["task20001_000"]}), tmp_path)
    assert [s.scene_id for s in scenes] == ["task20001_000"]


def test_physics_steps_a_free_fall(example_registry):
    physics = example_registry[1].get("physics", "example_euler")()
    spec = {"world": {"engine": "example_euler", "units": {"px_per_m": 6.0}, "dt_s": 1 / 60,
                      "gravity_m_s2": [0.0, -9.8], "steps_per_frame": 60,
                      "first_frame_after_steps": 1, "n_frames": 5},
            "bodies": [{"id": "ball", "dynamic": True,
                        "pose": {"x_px": 10.0, "y_px": 400.0, "angle_rad": 0.0},
                        "velocity": {"vx_px_s": 3.0, "vy_px_s": 0.0, "omega_rad_s": 0.0}}]}
    rollout = physics.simulate(spec)
    y = rollout.frame_poses[:, 0, 1]
    assert rollout.body_ids == ["ball"] and rollout.frame_steps.tolist() == [1, 61, 121, 181,
                                                                            241]
    np.testing.assert_allclose(y[2:] - 2 * y[1:-1] + y[:-2], -58.8)  # g · px/m · (1 s)²
    np.testing.assert_allclose(np.diff(rollout.frame_poses[:, 0, 0]), 3.0)


def test_listing_shows_every_example_plugin(example_env, tmp_path):
    out = run_cli("plugins", home=tmp_path, env=example_env).stdout
    for name in ENTRY_POINTS:
        row = next(line for line in out.splitlines() if line.startswith(f"│ {name} "))
        assert "visphy-plugin-example" in row


def test_allow_and_deny_lists_filter_the_plugin(example_env, tmp_path):
    out = run_cli("plugins", home=tmp_path,
                  env={**example_env, "VISPHY_DISABLE_PLUGINS": "visphy-plugin-example"}).stdout
    assert "example_" not in out and "oracle" in out
    out = run_cli("plugins", home=tmp_path,
                  env={**example_env, "VISPHY_DISABLE_PLUGINS": "example_judge"}).stdout
    assert "│ example_judge " not in out and "│ example_model " in out
    out = run_cli("plugins", home=tmp_path,
                  env={**example_env,
                       "VISPHY_LOAD_PLUGINS": "visphy-plugin-example,core_configs"}).stdout
    assert "example_still" in out and "oracle" not in out


def test_a_bad_value_of_an_example_config_is_one_line(example_env, tmp_path):
    proc = run_cli("judge=example_pixels", "judge.example_pixels.reduce=maxx", home=tmp_path,
                   env=example_env, check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        "error: judge.example_pixels.reduce=maxx is not a valid choice; valid: mean, max")


def test_a_run_uses_every_kind(example_env, tmp_path):
    """Replayed replies in the example engine's language, on the example dataset, scored by
    the example metric and judge, observed by the example lifecycle hooks: no browser, no key."""
    replies = tmp_path / "replies"
    replies.mkdir()
    for i in range(3):
        (replies / f"task2000{i}_000.txt").write_text(boxes_reply(60 + 30 * i, 40 * i))
    home = tmp_path / "home"
    run_cli("model=replay", f"model.source={replies}", "engine=example_boxes", "dataset=tiny",
            "dataset.source=example_squares", "metrics.names=[psnr,example_mae]",
            "metrics.variance_norm=false", "judge=example_pixels", "tracking=none",
            home=home, env=example_env)
    run_dir = next((home / "runs").iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["engine"] == "example_boxes" and summary["model_success"] == 3
    mae = summary["metrics"]["example_mae"]
    assert mae["direction"] == "lower" and 0 < mae["mean_model_success"] < 8
    assert summary["judges"]["example_pixels"]["n_valid"] == 3
    assert summary["example_log"] == "example_log.jsonl"
    log = [json.loads(line) for line in (run_dir / "example_log.jsonl").read_text().splitlines()]
    assert [e["event"] for e in log] == ["run_start"] + ["scene_done"] * 3 + ["run_end"]
    assert log[0]["engine"] == "example_boxes" and log[0]["scenes"] == 3
    assert all(e["model_success"] for e in log[1:4]) and log[-1]["status"] == "finished"


@pytest.mark.slow
@pytest.mark.browser
def test_example_model_runs_with_a_browser_engine(example_env, visphy_home):
    run_cli("model=example_still", "metrics.names=[psnr,example_mae]", "dataset.limit=2",
            "tracking=none", home=visphy_home, env=example_env)
    run_dir = next((visphy_home / "runs").iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["model"] == "example_still"
    mae = summary["metrics"]["example_mae"]
    assert mae["direction"] == "lower" and mae["n_model_success"] == 2
    assert mae["mean_model_success"] > 0  # a still frame differs from a moving scene
    rows = [json.loads(line) for line in (run_dir / "results.jsonl").read_text().splitlines()]
    assert all(r["model_success"] and "static_output" in r["flags"] for r in rows)
