"""Faults of one scene end in a classified row, never a crash: a bad input is ``data_error``, an
engine that raises is ``infra_error`` (retried once, no repair call, not counted against the
model); an interrupted loop closes the MLflow run; no secret reaches the run dir or the cache."""

from __future__ import annotations

import json
import os
import shutil
import signal
import sqlite3
from pathlib import Path

import pytest

from conftest import with_fast_metrics
from visphy_core.api.engine import Engine, FailureClass, Program, RenderResult
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.model import Model, ModelResponse


def _compose_run(home: Path, *overrides: str, plugins: dict | None = None):
    from visphy_core.api.registry import get_plugin_manager, get_registry
    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment

    pm = get_plugin_manager()
    for name, plugin in (plugins or {}).items():
        pm.register(plugin, name=name)
    get_registry.cache_clear()
    try:
        cfg = compose(list(with_fast_metrics((f"paths.root={home}", "tracking=none",
                                              "run.progress=false", "model=oracle",
                                              "engine=threejs", *overrides))))
        return run_experiment(cfg)
    finally:
        for name in plugins or {}:
            pm.unregister(name=name)
        get_registry.cache_clear()


def _rows(summary: dict) -> list[dict]:
    path = Path(summary["run_dir"]) / "results.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture
def home(tmp_path, mini_root):
    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


def _middle(home: Path, mini_root: Path) -> tuple[Path, str]:
    from visphy_plugins.datasets.visphybench.loader import load_generated

    root = home / "data" / mini_root.name
    return root, load_generated(root, split="mini")[1].scene_id


# --------------------------------------------------------------------------- data_error rows

def _break(kind: str, root: Path, sid: str) -> tuple[Path, str]:
    from visphy_core.infra.video import decode_video, encode_video

    if kind == "malformed_detection":
        path = root / "detection_json" / f"{sid}_frame_01.json"
        path.write_text('{"objects": [\n  {"id": "red_ball",}\n')
        return path, "malformed JSON"
    if kind == "binary_detection":
        path = root / "detection_json" / f"{sid}_frame_01.json"
        path.write_bytes(os.urandom(256))
        return path, "malformed JSON"
    if kind == "short_video":
        path = root / "videos" / f"{sid}.mp4"
        frames, info = decode_video(path)
        encode_video(frames[:5], path, info.fps)
        return path, "fewer than the key frame 10"
    if kind == "unreadable_video":
        path = root / "videos" / f"{sid}.mp4"
        path.write_bytes(os.urandom(4096))
        return path, "cannot decode video"
    if kind == "missing_video":
        path = root / "videos" / f"{sid}.mp4"
        path.unlink()
        return path, "not found"
    if kind == "missing_trajectory":
        path = root / "trajectories" / f"{sid}.npz"
        path.unlink()
        return path, "missing file"
    raise AssertionError(kind)


@pytest.mark.browser
@pytest.mark.parametrize("kind", ["malformed_detection", "short_video", "unreadable_video",
                                  "binary_detection", "missing_video", "missing_trajectory"])
def test_a_broken_middle_scene_is_one_data_error_row(home, mini_root, kind):
    root, sid = _middle(home, mini_root)
    path, needle = _break(kind, root, sid)
    summary = _compose_run(home, "dataset.limit=3")
    rows = _rows(summary)
    assert [r["scene_id"] for r in rows][1] == sid and len(rows) == 3
    ok = [r for r in rows if r["model_success"]]
    (bad,) = [r for r in rows if not r["model_success"]]
    assert len(ok) == 2 and all(r["score_psnr"] > 30 for r in ok)
    assert bad["scene_id"] == sid and bad["failure_class"] == "data_error"
    assert str(path) in bad["failure_detail"] and needle in bad["failure_detail"]
    assert "\n" not in bad["failure_detail"]
    assert bad["model_calls"] == 0 and bad["score_psnr"] is None and not bad["fallback"]
    assert summary["status"] == "finished" and summary["n_scenes"] == 3
    assert summary["n_evaluable"] == 2 and summary["model_success_rate_evaluable"] == 1.0
    assert summary["failures"] == {"model": {}, "infra_or_data": {"data_error": 1}}
    assert (Path(summary["run_dir"]) / "summary.json").is_file()
    assert (Path(summary["run_dir"]) / "results.parquet").is_file()


def test_the_original_layout_keeps_a_broken_scene_for_a_row(tmp_path, mini_scenes):
    """The lenient loader a run uses turns a scene's bad files into a data_error scene, while
    split-level errors still fail before any work."""
    from visphy_core.api.scene import SceneDataError
    from visphy_plugins.datasets.original import load_original

    split = tmp_path / "sub"
    (split / "videos").mkdir(parents=True)
    ids = ["task00001_000", "task00002_000", "task00003_000"]
    for sid, scene in zip(ids, mini_scenes):
        shutil.copyfile(scene.video_path, split / "videos" / f"{sid}.mp4")
    (split / "videos" / f"{ids[1]}.mp4").write_bytes(b"\x00not an mp4" * 20)
    with pytest.raises(ValueError):
        load_original(tmp_path, "sub")  # strict (the loader's own tests)
    scenes = load_original(tmp_path, "sub", strict=False)
    assert [s.scene_id for s in scenes] == ids
    assert scenes[0].load_error is None and "unreadable video" in scenes[1].load_error
    with pytest.raises(SceneDataError) as info:
        scenes[1].check_inputs()
    assert str(split / "videos" / f"{ids[1]}.mp4") in str(info.value)
    with pytest.raises(FileNotFoundError):
        load_original(tmp_path, "test", strict=False)  # dataset-level: still an error


# --------------------------------------------------------------------------- infra_error rows

def _exploding_engine(failures: int):
    from visphy_plugins.engines.threejs import ThreeJsEngine

    class Exploding(ThreeJsEngine):
        """threejs whose first ``failures`` renders raise (a browser that went away)."""

        name = "exploding"
        calls = 0

        def render(self, program, contract):
            type(self).calls += 1
            if type(self).calls <= failures:
                raise RuntimeError(f"browser connection lost (call {type(self).calls})")
            return super().render(program, contract)

    class Plugin:
        @hookimpl
        def visphy_register_engines(self, register):
            register("exploding", Exploding)

    return Exploding, Plugin()


@pytest.mark.browser
def test_an_engine_exception_is_infra_error_retried_once_without_repair(home):
    engine, plugin = _exploding_engine(failures=2)
    summary = _compose_run(home, "dataset.limit=2", "engine.name=exploding",
                           plugins={"exploding": plugin})
    first, second = _rows(summary)
    assert engine.calls == 3  # scene 1: render + one infra retry; scene 2: one render
    assert first["failure_class"] == "infra_error" and first["infra_retries"] == 1
    assert "RuntimeError: browser connection lost (call 2)" in first["failure_detail"]
    assert first["attempts"] == 1 and first["model_calls"] == 1  # no repair call
    assert not first["fallback"] and first["score_psnr"] is None
    scene_dir = Path(summary["run_dir"]) / "scenes" / first["scene_id"]
    assert not (scene_dir / "repair_prompt.txt").exists()
    assert not (scene_dir / "response.attempt2.txt").exists()
    assert "call 1" in (scene_dir / "render.log").read_text()
    assert second["model_success"] and second["score_psnr"] > 30
    assert summary["model_success"] == 1 and summary["model_success_rate"] == 0.5
    assert summary["n_evaluable"] == 1 and summary["model_success_rate_evaluable"] == 1.0
    assert summary["failures"] == {"model": {}, "infra_or_data": {"infra_error": 1}}


@pytest.mark.browser
def test_a_transient_infra_error_is_absorbed_by_the_retry(home):
    engine, plugin = _exploding_engine(failures=1)
    summary = _compose_run(home, "dataset.limit=1", "engine.name=exploding",
                           plugins={"exploding": plugin})
    (row,) = _rows(summary)
    assert row["model_success"] and row["infra_retries"] == 1 and row["attempts"] == 1
    assert row["model_calls"] == 1 and engine.calls == 2


class _Raiser:
    """A lifecycle plugin whose scene hook fails after the first scene."""

    def __init__(self, action):
        self.action = action

    @hookimpl
    def visphy_scene_done(self, run, scene, result):
        self.action()


@pytest.mark.browser
@pytest.mark.parametrize("how, mlflow_status, status", [
    ("exception", "FAILED", "failed"), ("sigterm", "KILLED", "interrupted")])
def test_an_interrupted_loop_ends_the_mlflow_run(home, how, mlflow_status, status):
    from visphy_core.execute.run_signals import RunInterrupted

    def action():
        if how == "exception":
            raise RuntimeError("plugin bug")
        os.kill(os.getpid(), signal.SIGTERM)

    expected = RuntimeError if how == "exception" else RunInterrupted
    with pytest.raises(expected) as info:
        _compose_run(home, "dataset.limit=3", "tracking=mlflow",
                     plugins={"raiser": _Raiser(action)})
    if how == "sigterm":
        assert info.value.code == 143
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # handlers restored
    (run_dir,) = (home / "runs").iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert summary["status"] == status == manifest["status"]
    assert summary["n_scenes"] == 1 and summary["n_selected"] == 3
    assert (run_dir / "results.parquet").is_file()
    with sqlite3.connect(home / "mlflow.db") as con:
        assert [s for (s,) in con.execute("select status from runs")] == [mlflow_status]


# --------------------------------------------------------------------------- secrets

SECRET = "sk-canary-7f3a9b2e41d8c6"


class LeakyEngine(Engine):
    """Stands for a program that escaped containment and printed a secret: the render fails with
    the secret in its error and its log (redaction is the second line of defence)."""

    name, language, version = "leaky", "html", "1"
    renders = 0

    def extract(self, text):
        return Program("html", text)

    def validate(self, program):
        pass

    def render(self, program, contract):
        type(self).renders += 1
        value = os.environ["VISPHY_TEST_API_KEY"]
        return RenderResult(frames=None, failure=FailureClass.RUNTIME_ERROR,
                            error=f"Error: leaked {value}",
                            logs=[f"console: the key is {value}", "done"], isolation="test")

    def program_from_spec(self, scene):
        raise NotImplementedError


class RecordingModel(Model):
    name = "recording"
    prompts: list[str] = []

    def generate(self, request):
        type(self).prompts.append(request.prompt)
        return ModelResponse(text="<html><body>program</body></html>")


def test_a_printed_secret_never_reaches_the_run_dir_or_cache(home, monkeypatch):
    monkeypatch.setenv("VISPHY_TEST_API_KEY", SECRET)

    class Plugin:
        @hookimpl
        def visphy_register_engines(self, register):
            register("leaky", LeakyEngine)

        @hookimpl
        def visphy_register_models(self, register):
            register("recording", RecordingModel)

    RecordingModel.prompts = []
    summary = _compose_run(home, "dataset.limit=1", "engine.name=leaky", "model.name=recording",
                           plugins={"leaky": Plugin()})
    (row,) = _rows(summary)
    assert row["failure_class"] == "runtime_error" and row["fallback"]
    assert row["isolation"] == "test"
    assert "[REDACTED:VISPHY_TEST_API_KEY]" in row["failure_detail"]
    assert len(RecordingModel.prompts) == 2  # the repair call happened ...
    assert SECRET not in RecordingModel.prompts[1]  # ... without the secret
    assert "[REDACTED:VISPHY_TEST_API_KEY]" in RecordingModel.prompts[1]
    scene_dir = Path(summary["run_dir"]) / "scenes" / row["scene_id"]
    assert "[REDACTED:VISPHY_TEST_API_KEY]" in (scene_dir / "render.log").read_text()
    assert (scene_dir / "repair_prompt.txt").is_file()
    leaks = [p for p in home.rglob("*") if p.is_file() and SECRET.encode() in p.read_bytes()]
    assert leaks == []
