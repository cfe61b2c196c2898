"""One test per hook (test_hookspecs.py fails if a hook has none): inline plugins, llm style."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from conftest import FAST_METRICS
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import HIGHER, Metric
from visphy_core.api.registry import PluginError, build_plugin_manager, build_registry


@pytest.fixture
def pm():
    return build_plugin_manager()


def test_visphy_register_configs(pm):
    from hydra.core.config_store import ConfigStore

    @dataclass
    class InlineModelConfig:
        name: str = "inline_model"
        temperature: float = 0.0

    class Plugin:
        @hookimpl
        def visphy_register_configs(self, config_store):
            config_store.store(group="model", name="inline_model", node=InlineModelConfig)

    pm.register(Plugin(), name="inline")
    registry = build_registry(pm)
    assert registry.configs["model/inline_model"][1] == "inline"
    assert ConfigStore.instance().repo["model"]["inline_model.yaml"].node.temperature == 0.0


def test_visphy_register_models(pm):
    class Plugin:
        @hookimpl
        def visphy_register_models(self, register):
            register("inline_a", lambda cfg: "A")
            register("inline_b", lambda cfg: "B")

    pm.register(Plugin(), name="inline")
    registry = build_registry(pm)
    assert registry.get("models", "inline_b")(None) == "B"
    assert registry.models["inline_a"][1] == "inline"
    assert "oracle" in registry.models  # built-ins come through the same entry-point path
    with pytest.raises(KeyError, match="unknown model 'nope'; installed: .*inline_a"):
        registry.get("models", "nope")


def test_visphy_register_engines(pm):
    class Plugin:
        @hookimpl
        def visphy_register_engines(self, register):
            register("threejs", lambda cfg: None)  # clashes with the built-in engine

    pm.register(Plugin(), name="clash")
    with pytest.raises(PluginError, match="engine 'threejs' registered twice"):
        build_registry(pm)


def test_visphy_register_metrics(pm):
    class Constant(Metric):
        name, direction, score_range = "inline_const", HIGHER, (0.0, 1.0)

        def compute(self, inp):
            return 0.5

    class Plugin:
        @hookimpl
        def visphy_register_metrics(self, register):
            register(Constant())

    pm.register(Plugin(), name="inline")
    metric = build_registry(pm).get("metrics", "inline_const")
    assert metric.describe() == {"name": "inline_const", "direction": "higher",
                                 "range": [0.0, 1.0], "needs": ["frames"], "family": "pixel",
                                 "kind": "scene", "weights": None, "max_pairs": None,
                                 "unavailable": None, "validity": None}


def test_visphy_register_judges(pm):
    class Plugin:
        @hookimpl
        def visphy_register_judges(self, register):
            register("inline_judge", lambda cfg: "judge")

    pm.register(Plugin(), name="inline")
    registry = build_registry(pm)
    assert registry.get("judges", "inline_judge")(None) == "judge"
    with pytest.raises(PluginError, match="needs a factory"):
        class Bad:
            @hookimpl
            def visphy_register_judges(self, register):
                register("broken", "not callable")

        pm.register(Bad(), name="bad")
        build_registry(pm)


def test_visphy_register_datasets(pm, tmp_path):
    from visphy_core.api.dataset import Dataset
    from visphy_core.api.scene import Scene
    from visphy_core.infra.video import ClipInfo

    class Listing(Dataset):
        name = "listing"

        def load(self, cfg, data_dir, progress=True):
            clip = ClipInfo(fps=5.0, n_frames=17, width=64, height=64)
            return [Scene(scene_id=f"task{10000 + i:05d}_000", dim="2d", clip=clip,
                          video_path=data_dir / f"{i}.mp4") for i in range(cfg["n"])]

    class Plugin:
        @hookimpl
        def visphy_register_datasets(self, register):
            register("listing", Listing)

    pm.register(Plugin(), name="inline")
    registry = build_registry(pm)
    dataset = registry.get("datasets", "listing")()
    assert [s.scene_id for s in dataset.load({"n": 2}, tmp_path)] == ["task10000_000",
                                                                     "task10001_000"]
    with pytest.raises(NotImplementedError, match="not generated"):
        dataset.build(tmp_path)
    # the built-in sources are plugins of the same hook
    assert {"generated", "original", "tiny"} <= set(registry.datasets)
    assert registry.datasets["generated"][1] == "dataset_visphybench"
    with pytest.raises(KeyError, match="unknown dataset 'nope'; installed: .*listing"):
        registry.get("datasets", "nope")
    with pytest.raises(PluginError, match="dataset 'listing' registered twice"):
        class Twice:
            @hookimpl
            def visphy_register_datasets(self, register):
                register("listing", Listing)

        pm.register(Twice(), name="twice")
        build_registry(pm)


def test_visphy_register_physics(pm):
    from visphy_core.api.physics import Physics, physics_for

    class Ballistic(Physics):
        """A point mass under gravity, nothing else."""

        name, dim = "ballistic", "2d"

        def simulate(self, spec, timeout_s=60.0):
            t = np.arange(spec["n"]) / 5.0
            y = spec["y0"] - 0.5 * 9.8 * t ** 2

            @dataclass
            class R:
                body_ids: list
                frame_poses: np.ndarray
                frame_steps: np.ndarray
                frame_times_s: np.ndarray

            poses = np.stack([np.zeros_like(t), y, np.zeros_like(t)], axis=1)[:, None, :]
            return R(["ball"], poses, np.arange(spec["n"]), t)

    class Plugin:
        @hookimpl
        def visphy_register_physics(self, register):
            register("ballistic", Ballistic)

    pm.register(Plugin(), name="inline")
    registry = build_registry(pm)
    rollout = registry.get("physics", "ballistic")().simulate({"n": 3, "y0": 10.0})
    assert rollout.frame_poses[:, 0, 1].tolist() == pytest.approx([10.0, 9.804, 9.216])
    # scene specs name their simulator in world.engine; the built-ins are plugins too
    assert {"box2d", "cannon-es"} <= set(registry.physics)
    assert physics_for({"world": {"engine": "box2d"}}).dim == "2d"
    assert physics_for({"world": {"engine": "cannon-es"}}).dim == "3d"
    with pytest.raises(KeyError, match="unknown physics engine 'havok'; installed: box2d"):
        physics_for({"world": {"engine": "havok"}})


class Recorder:
    """Records every lifecycle call of a real (tiny) run."""

    def __init__(self):
        self.calls = []

    @hookimpl
    def visphy_run_start(self, run):
        self.calls.append(("start", len(run.scenes), run.run_dir.is_dir()))

    @hookimpl
    def visphy_scene_done(self, run, scene, result):
        self.calls.append(("scene", scene.scene_id, result.system_success))

    @hookimpl
    def visphy_run_end(self, run, summary):
        self.calls.append(("end", summary["n_scenes"],
                           (run.run_dir / "summary.json").is_file()))


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory, mini_root):
    """One real run of two mini scenes with the Recorder plugin registered."""
    import shutil

    from visphy_core.api.registry import get_plugin_manager
    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment

    home = tmp_path_factory.mktemp("home")
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    cfg = compose([f"paths.root={home}", "dataset.limit=2", "tracking=none",
                   "run.progress=false", *FAST_METRICS])
    recorder = Recorder()
    pm = get_plugin_manager()
    pm.register(recorder, name="recorder")
    try:
        summary = run_experiment(cfg)
    finally:
        pm.unregister(name="recorder")
    return recorder.calls, summary


@pytest.mark.browser
def test_visphy_run_start(recorded_run):
    calls, _ = recorded_run
    assert calls[0] == ("start", 2, True)


@pytest.mark.browser
def test_visphy_scene_done(recorded_run):
    calls, summary = recorded_run
    scenes = [c for c in calls if c[0] == "scene"]
    assert len(scenes) == summary["n_scenes"] == 2
    assert all(ok for _, _, ok in scenes)


@pytest.mark.browser
def test_visphy_run_end(recorded_run):
    calls, summary = recorded_run
    assert calls[-1] == ("end", 2, True)
    written = json.loads((__import__("pathlib").Path(summary["run_dir"]) / "summary.json")
                         .read_text())
    assert written["n_scenes"] == 2
    assert np.isfinite(written["metrics"]["psnr"]["mean_model_success"])
