"""Local video models (``svd``, ``cosmos``): every unavailable path is one line naming what is
missing, and nothing stands in for the model (no canned video). The models themselves need
diffusers, torch, a GPU and weights, none of which this test environment has."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from visphy_core.api.errors import UserError
from visphy_core.api.media import png_bytes
from visphy_core.api.model import ImageInput, ModelRequest, OutputContract
from visphy_core.api.registry import get_registry
from visphy_core.config.check import compose
from visphy_plugins.models import local_video

REAL_FIND_SPEC = importlib.util.find_spec


def model(name: str, *overrides: str):
    get_registry()
    cfg = compose([f"model={name}", *overrides]).model
    return get_registry().get("models", name)(cfg)


def reason(m) -> str:
    with pytest.raises(UserError) as info:
        m.check_ready()
    text = str(info.value)
    assert "\n" not in text and text.startswith(f"model={m.name} cannot run here: ")
    return text


@pytest.fixture(autouse=True)
def no_weights_env(monkeypatch):
    monkeypatch.delenv("VISPHY_WEIGHTS", raising=False)


def pretend_installed(monkeypatch, *modules: str):
    def find_spec(name, *args, **kwargs):
        if name in modules:
            return object()
        return REAL_FIND_SPEC(name, *args, **kwargs)
    monkeypatch.setattr(local_video.importlib.util, "find_spec", find_spec)


def checkpoint(path, cls: str):
    path.mkdir(parents=True)
    (path / "model_index.json").write_text(json.dumps({"_class_name": cls}))
    return path


def pretend_missing(monkeypatch, *modules: str):
    def find_spec(name, *args, **kwargs):
        if name in modules:
            return None
        return REAL_FIND_SPEC(name, *args, **kwargs)
    monkeypatch.setattr(local_video.importlib.util, "find_spec", find_spec)


def test_missing_packages_and_weights_in_one_line(monkeypatch):
    # torch is part of the default install now: hide it (and diffusers) as a machine without
    # them would
    pretend_missing(monkeypatch, "diffusers", "torch", "cosmos_guardrail")
    text = reason(model("svd"))
    assert "diffusers and torch are not installed (pip install diffusers torch)" in text
    assert "model.weights_dir" in text and "$VISPHY_WEIGHTS/svd" in text
    assert "StableVideoDiffusionPipeline" in text and "model_index.json" in text
    text = reason(model("cosmos"))
    assert "pip install diffusers torch cosmos_guardrail" in text
    assert "Cosmos2_5_PredictBasePipeline" in text and "Cosmos-Predict2.5-2B" in text


def test_weights_dir_from_the_environment_must_exist(monkeypatch, tmp_path):
    pretend_installed(monkeypatch, "diffusers", "torch")
    monkeypatch.setenv("VISPHY_WEIGHTS", str(tmp_path))
    text = reason(model("svd", "model.device=cpu"))
    assert f"weights directory {tmp_path / 'svd'} does not exist" in text
    assert "model_index.json" in text and "stable-video-diffusion-img2vid-xt" in text
    assert "not installed" not in text


def test_weights_dir_without_a_checkpoint(monkeypatch, tmp_path):
    pretend_installed(monkeypatch, "diffusers", "torch")
    (tmp_path / "w").mkdir()
    text = reason(model("svd", "model.device=cpu", f"model.weights_dir={tmp_path / 'w'}"))
    assert f"{tmp_path / 'w'} has no model_index.json" in text


def test_checkpoint_of_another_pipeline(monkeypatch, tmp_path):
    pretend_installed(monkeypatch, "diffusers", "torch", "cosmos_guardrail")
    w = checkpoint(tmp_path / "c", "Cosmos2VideoToWorldPipeline")
    text = reason(model("cosmos", "model.device=cpu", f"model.weights_dir={w}"))
    assert "holds a Cosmos2VideoToWorldPipeline checkpoint" in text
    assert "set model.pipeline=Cosmos2VideoToWorldPipeline" in text
    model("cosmos", "model.device=cpu", f"model.weights_dir={w}",
          "model.pipeline=Cosmos2VideoToWorldPipeline").check_ready()


def test_cosmos_needs_its_guardrail_package(monkeypatch, tmp_path):
    pretend_installed(monkeypatch, "diffusers", "torch")
    w = checkpoint(tmp_path / "c", "Cosmos2_5_PredictBasePipeline")
    text = reason(model("cosmos", "model.device=cpu", f"model.weights_dir={w}"))
    if REAL_FIND_SPEC("cosmos_guardrail") is None:
        assert "cosmos_guardrail is not installed (pip install cosmos_guardrail)" in text


def test_ready_when_everything_is_there(monkeypatch, tmp_path):
    pretend_installed(monkeypatch, "diffusers", "torch")
    monkeypatch.setenv("VISPHY_WEIGHTS", str(tmp_path))
    checkpoint(tmp_path / "svd", "StableVideoDiffusionPipeline")
    m = model("svd", "model.device=cpu")
    m.check_ready()
    assert m.weights_dir() == tmp_path / "svd"
    # where the weights live is not part of the cache identity; the seed is
    assert m.identity() == model("svd", "model.device=cpu", "model.weights_dir=/x").identity()
    assert m.identity() != model("svd", "model.device=cpu", "model.seed=1").identity()


def test_generate_without_prerequisites_returns_the_reason_not_a_video():
    m = model("svd")
    frame = np.full((64, 64, 3), 255, np.uint8)
    req = ModelRequest(scene_id="s", prompt="p", images=[ImageInput("frame_01", png_bytes(frame))],
                       detection=None, engine_name="video", language="mp4",
                       output=OutputContract(5.0, 17, 64, 64))
    resp = m.generate(req)
    assert resp.video_path is None and resp.error_kind == "bad_request"
    assert "weights" in resp.error and m.output_kind == "video"
