"""Where weights are searched, what a missing weight says, and how `metrics.*` selects metrics."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from visphy_core import weights
from visphy_core.plugins import get_registry
from visphy_core.scoring import select_metrics, subsample_pairs


@pytest.fixture(autouse=True)
def _reset(monkeypatch, tmp_path):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.delenv("VISPHY_WEIGHTS", raising=False)
    yield
    weights.configure(None)


def test_the_configured_dir_wins_then_the_env_then_the_torch_hub_cache(tmp_path, monkeypatch):
    hub = weights.torch_hub_checkpoints()
    assert hub == tmp_path / "torch" / "hub" / "checkpoints"
    hub.mkdir(parents=True)
    (hub / "w.pth").write_bytes(b"hub")
    assert weights.find("w.pth") == hub / "w.pth"
    env_dir = tmp_path / "env"
    env_dir.mkdir()
    (env_dir / "w.pth").write_bytes(b"env")
    monkeypatch.setenv("VISPHY_WEIGHTS", str(env_dir))
    assert weights.find("w.pth") == env_dir / "w.pth"
    conf_dir = tmp_path / "conf"
    conf_dir.mkdir()
    (conf_dir / "w.pth").write_bytes(b"conf")
    weights.configure(conf_dir, "cpu")
    assert weights.find("nope.pth", "w.pth") == conf_dir / "w.pth"
    assert weights.search_dirs()[:3] == [conf_dir, env_dir, hub]


def test_a_missing_weight_names_the_file_and_every_place_searched(tmp_path):
    weights.configure(tmp_path / "mine")
    why = weights.missing("RAFT large", ["raft.pth"], "torchvision's file")
    assert "raft.pth" in why and "metrics.weights_dir" in why
    assert str(tmp_path / "mine") in why and "torchvision's file" in why
    assert weights.find("raft.pth") is None


def test_the_digest_follows_the_content(tmp_path):
    f = tmp_path / "w.pth"
    f.write_bytes(b"one")
    first = weights.digest(f)
    f.write_bytes(b"two!")
    assert weights.digest(f) != first
    d = tmp_path / "model"
    d.mkdir()
    (d / "a.bin").write_bytes(b"x")
    assert len(weights.digest(d)) == 16


def test_select_metrics_applies_max_pairs_to_copies_and_configures_weights(tmp_path):
    registry = get_registry()
    cfg = OmegaConf.create({"names": ["psnr", "fsim"], "max_pairs": {"psnr": 3},
                            "weights_dir": str(tmp_path), "device": "cpu"})
    psnr, fsim = select_metrics(registry, cfg)
    assert psnr.max_pairs == 3 and registry.get("metrics", "psnr").max_pairs is None
    assert "max_pairs=3" in psnr.identity()
    assert fsim is registry.get("metrics", "fsim")
    assert weights.search_dirs()[0] == tmp_path and weights.device() == "cpu"


def test_subsampling_keeps_the_ends_and_spreads_evenly():
    pairs = [(i, i) for i in range(17)]
    assert subsample_pairs(pairs, None) == pairs
    picked = subsample_pairs(pairs, 5)
    assert picked[0] == (0, 0) and picked[-1] == (16, 16) and len(picked) == 5
    assert subsample_pairs(pairs, 1) == [(0, 0)]


def test_an_empty_directory_never_hides_a_hugging_face_cache_copy(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    weights.configure(tmp_path / "w")
    (tmp_path / "w" / "roberta-large").mkdir(parents=True)  # empty: not a model
    snap = tmp_path / "hf" / "hub" / "models--FacebookAI--roberta-large" / "snapshots" / "abc"
    snap.mkdir(parents=True)
    (snap / "config.json").write_text("{}")
    assert weights.find_hf("FacebookAI/roberta-large") == snap
    (tmp_path / "w" / "roberta-large" / "config.json").write_text("{}")
    assert weights.find_hf("FacebookAI/roberta-large") == tmp_path / "w" / "roberta-large"
