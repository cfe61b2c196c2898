"""Visual semantics: CLIP and DINO embeddings of the frames (family ``semantic``, higher is better).

Each metric is named after the model it runs, and runs no other (docs/metrics.md; the paper's models
are upstream's ``utils/evaluate_video_metrics.py``: open_clip ``ViT-B-32`` pretrained
``laion2b_s34b_b79k``, timm ``vit_base_patch16_224.dino`` first): a different checkpoint is a
different metric, never a silent stand-in.

* ``clip_img`` (kind ``pairs``, range [−1, 1]): the cosine between the CLIP ViT-B/32 image
  embeddings (open_clip ``ViT-B-32``, ``laion2b_s34b_b79k``: the paper's CLIP) of the reference
  frame and the generated frame of each pair.
* ``clip_cap`` (kind ``scene``, range [−1, 1]): the cosine between the CLIP text embedding of the
  model's whole analysis and the mean CLIP image embedding of the generated clip. The analysis is
  never truncated: its n BPE tokens are cut into ⌈n / 75⌉ balanced chunks of at most 75 tokens
  (77 with the start/end tokens), at word ends (more chunks only where the word ends force it;
  `text_chunks`); each chunk is embedded, the L2-normalised chunk embeddings are averaged and
  the mean normalised again. The frames are
  `CLIP_CAP_FRAMES` (8) of the generated clip, evenly spaced in time, first and last included
  (every frame of a shorter clip); their normalised embeddings are averaged and normalised. No
  analysis (or one with no token): NaN, which the scorer records as None.
* ``clip_img_openai``, ``clip_cap_openai``: the same with OpenAI's CLIP ViT-B/32 checkpoint
  (open_clip ``ViT-B-32-quickgelu``, ``openai``), a different model from the paper's.
* ``dino`` (kind ``pairs``, range [−1, 1]): the cosine between the DINO ViT-B/16 CLS features
  (timm ``vit_base_patch16_224.dino``, the paper's DINO: the CLS token after the final norm,
  DINO's own output) of the two frames of each pair.
* ``dino_vits16``: the same with DINO ViT-S/16 (timm ``vit_small_patch16_224.dino``), a quarter
  of ViT-B/16's cost on a CPU, a different model from the paper's.

Preprocessing runs batched in torch. CLIP follows open_clip's own transform for the model
(``model.visual.preprocess_cfg``): the shorter side resized to 224 (bicubic, antialiased), a
centre crop of 224², OpenAI's mean/std; the resize runs on the uint8 frames with torch's
antialiased uint8 kernels, which reproduce PIL's: open_clip's PIL pipeline gives the same
input up to rounding (at most 1 grey level for square frames, 2 otherwise; under 0.01 on
average). DINO sees the whole frame resized to 224² (bicubic, antialiased; no crop, so objects
at the border count), ImageNet mean/std.

Weights are never downloaded; they are found by `visphy_core.api.weights`
(``metrics.weights_dir``,
then ``$VISPHY_WEIGHTS``, then ``$TORCH_HOME/hub/checkpoints``, then the Hugging Face hub cache):

CLIP (the names are relative to a searched directory; the first hit wins):

* ``clip_img``/``clip_cap``: ``laion/CLIP-ViT-B-32-laion2B-s34B-b79K/open_clip_model.safetensors``,
  the same under ``CLIP-ViT-B-32-laion2B-s34B-b79K/``, or flat ``open_clip_model.safetensors``
  (the file of the Hugging Face repo ``laion/CLIP-ViT-B-32-laion2B-s34B-b79K``), else a snapshot
  of that repo in the Hugging Face hub cache → open_clip ``ViT-B-32``, loaded with
  ``pretrained=<file>``. (The repo's ``open_clip_pytorch_model.bin`` holds the same weights but
  is not accepted: no published SHA-256 was found to verify it against.)
* ``clip_img_openai``/``clip_cap_openai``: ``ViT-B-32.pt``, OpenAI's CLIP checkpoint (JIT archive
  or state dict), else ``~/.cache/clip/ViT-B-32.pt`` (the ``clip`` package's download cache) →
  ``ViT-B-32-quickgelu`` (open_clip's OpenAI loader).

DINO:

* ``dino`` (ViT-B/16, timm ``vit_base_patch16_224.dino``):
  ``timm/vit_base_patch16_224.dino/model.safetensors`` (or ``pytorch_model.bin``; also under
  ``vit_base_patch16_224.dino/``), ``dino_vitbase16_pretrain.pth`` (FAIR's file, also what
  ``torch.hub`` caches in ``$TORCH_HOME/hub/checkpoints``), or a hub-cache snapshot of
  ``timm/vit_base_patch16_224.dino``;
* ``dino_vits16`` (ViT-S/16, ``vit_small_patch16_224.dino``): the same names with
  ``vit_small_patch16_224.dino`` and ``dino_deitsmall16_pretrain.pth``.

Loaded through timm with ``pretrained_cfg_overlay=dict(file=<path>)``. Every file is checked
against its published SHA-256 first (`visphy_core.api.weights.check`): a wrong file makes the
metric
unavailable (``checksum mismatch …``), a file with no published SHA-256 too (record the one its
publisher lists in ``SHA256SUMS``, see `visphy_core.api.weights`). The model used is recorded in
``weights``, in ``describe()["model"]`` and in the identity (with the weights' digest).

Cost: models load once per process (keyed by weight file, size, mtime and device); every frame is
embedded once per process (memoised by its content digest, `_EMBED_MEMO` entries at most), so the
pairings of a scene and ``clip_img``/``clip_cap`` share the embeddings (``clip_cap``'s 8 frames
are the generated frames of ``clip_img``'s unaligned pairing). ``max_pairs`` defaults to
`CLIP_MAX_PAIRS` and `DINO_MAX_PAIRS` (8) per pairing (``metrics.max_pairs.<name>`` overrides):
with the three pairings that is about 30 distinct frames for a 17-frame clip and 40 for a 75-frame
clip, ≈ 0.2 CPU-seconds per frame and model for CLIP ViT-B/32 and DINO ViT-S/16 (both ≈ 4.5
GFLOPs); DINO ViT-B/16 is ≈ 17.6 GFLOPs, about four times that.
"""
# size: CLIP and DINO share frame sampling, weight loading and the embedding cache

from __future__ import annotations

import hashlib
import math
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from visphy_core.api import weights as _weights
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import HIGHER, PAIRS, SCENE, Metric, MetricInput

# --------------------------------------------------------------------------- settings
CLIP_HF_REPO = "laion/CLIP-ViT-B-32-laion2B-s34B-b79K"
CLIP_OPEN_CLIP_FILES = ("open_clip_model.safetensors",)
CLIP_OPENAI_FILE = "ViT-B-32.pt"
#: The frames of the generated clip that ``clip_cap`` embeds (evenly spaced, ends included).
CLIP_CAP_FRAMES = 8
#: Text tokens per CLIP chunk: the context of 77 less the start and end tokens.
CLIP_CHUNK_TOKENS = 75

DINO_VARIANTS = (
    # (timm model name, FAIR's checkpoint file name): ``dino`` (the paper's), ``dino_vits16``
    ("vit_base_patch16_224.dino", "dino_vitbase16_pretrain.pth"),
    ("vit_small_patch16_224.dino", "dino_deitsmall16_pretrain.pth"),
)
DINO_HF_FILES = ("model.safetensors", "pytorch_model.bin")
DINO_SIZE = 224
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

CLIP_MAX_PAIRS = 8
DINO_MAX_PAIRS = 8
#: Frames per forward pass.
BATCH = 16
#: Frame embeddings kept per process (a few kB each).
_EMBED_MEMO = 8192


# --------------------------------------------------------------------------- finding weights
@dataclass(frozen=True)
class Found:
    """A weight file and what it holds."""

    path: Path
    arch: str        # open_clip model name or timm model name
    source: str      # pretrained tag / provenance
    label: str       # human-readable model name (``weights``, ``describe()["model"]``)
    key: str = ""    # the artifact's key in `visphy_core.api.weights.PUBLISHED` (its checksum)

    def problem(self) -> str | None:
        """None when the file is the published one; else why it must not be used."""
        return _weights.check(self.path, self.key or self.path.name)


def _file_in(directory: Path, names: tuple[str, ...]) -> Path | None:
    for n in names:
        if (directory / n).is_file():
            return directory / n
    return None


def _is_file(p: Path | None) -> Path | None:
    return p if p is not None and p.is_file() else None


#: The two CLIP ViT-B/32 checkpoints: ``laion`` (the paper's: clip_img, clip_cap) and
#: ``openai`` (clip_img_openai, clip_cap_openai).
CLIP_LAION, CLIP_OPENAI = "laion2b_s34b_b79k", "openai"
_CLIP_LABELS = {CLIP_LAION: "CLIP ViT-B/32 (open_clip laion2b_s34b_b79k)",
                CLIP_OPENAI: "CLIP ViT-B/32 (OpenAI)"}


def _laion(p: Path) -> Found:
    return Found(p, "ViT-B-32", CLIP_LAION, _CLIP_LABELS[CLIP_LAION],
                 key=f"{CLIP_HF_REPO}/{p.name}")


def _openai(p: Path) -> Found:
    return Found(p, "ViT-B-32-quickgelu", CLIP_OPENAI, _CLIP_LABELS[CLIP_OPENAI],
                 key=f"openai/{CLIP_OPENAI_FILE}")


def find_clip(source: str = CLIP_LAION) -> Found | None:
    """The CLIP ViT-B/32 weights of ``source`` (`CLIP_LAION` or `CLIP_OPENAI`) this machine has
    (see the module docstring), or None. Never the other checkpoint."""
    if source == CLIP_OPENAI:
        hit = _is_file(_weights.find(CLIP_OPENAI_FILE)) \
            or _is_file(Path(os.path.expanduser("~/.cache/clip")) / CLIP_OPENAI_FILE)
        return _openai(hit) if hit is not None else None
    last = CLIP_HF_REPO.split("/")[-1]
    names = [f"{d}/{f}" for d in (CLIP_HF_REPO, last) for f in CLIP_OPEN_CLIP_FILES] \
        + list(CLIP_OPEN_CLIP_FILES)
    hit = _is_file(_weights.find(*names))
    if hit is None:
        snap = _weights.find_hf(CLIP_HF_REPO)
        hit = _file_in(snap, CLIP_OPEN_CLIP_FILES) if snap is not None else None
    return _laion(hit) if hit is not None else None


def clip_missing(source: str = CLIP_LAION) -> str:
    if source == CLIP_OPENAI:
        return _weights.missing(
            "OpenAI's CLIP ViT-B/32 checkpoint", [CLIP_OPENAI_FILE],
            extra=(f"{CLIP_OPENAI_FILE} is the file OpenAI's clip package downloads (also "
                   "used from ~/.cache/clip); the paper's CLIP is clip_img/clip_cap "
                   "(open_clip laion2b_s34b_b79k)"))
    last = CLIP_HF_REPO.split("/")[-1]
    return _weights.missing(
        "CLIP ViT-B/32 (open_clip laion2b_s34b_b79k)",
        [f"{last}/open_clip_model.safetensors", "open_clip_model.safetensors"],
        extra=(f"open_clip_model.safetensors is the file of the Hugging Face repo {CLIP_HF_REPO}"
               " (open_clip ViT-B-32, pretrained laion2b_s34b_b79k; a copy in the Hugging Face "
               "hub cache is used too); its open_clip_pytorch_model.bin is not accepted (no "
               "published SHA-256 to verify it against); OpenAI's ViT-B-32.pt is another "
               "model: clip_img_openai/clip_cap_openai"))


def _dino_names(model: str, fair: str) -> list[str]:
    return [f"{d}/{f}" for d in (f"timm/{model}", model) for f in DINO_HF_FILES] + [fair]


def _dino_label(model: str) -> str:
    return f"DINO {'ViT-B/16' if 'base' in model else 'ViT-S/16'} (timm {model})"


def find_dino(model: str = DINO_VARIANTS[0][0]) -> Found | None:
    """The weights of the DINO ViT ``model`` (a timm name of `DINO_VARIANTS`; default ViT-B/16,
    the paper's) this machine has, or None. Never another variant."""
    fair = dict(DINO_VARIANTS)[model]
    hit = _is_file(_weights.find(*_dino_names(model, fair)))
    if hit is None:
        snap = _weights.find_hf(f"timm/{model}")
        hit = _file_in(snap, DINO_HF_FILES) if snap is not None else None
    if hit is None:
        return None
    key = fair if hit.name == fair else f"timm/{model}/{hit.name}"
    return Found(hit, model, "dino", _dino_label(model), key=key)


def dino_missing(model: str = DINO_VARIANTS[0][0]) -> str:
    fair = dict(DINO_VARIANTS)[model]
    other = ("dino_vits16 (ViT-S/16) is the same metric with the smaller model" if "base" in model
             else "the paper's DINO is dino (ViT-B/16)")
    return _weights.missing(
        _dino_label(model), [f"{model}/model.safetensors", fair],
        extra=(f"model.safetensors / pytorch_model.bin are the files of the Hugging Face repo "
               f"timm/{model} (also accepted under timm/{model}/, or as a Hugging Face hub cache "
               f"snapshot); {fair} is FAIR's checkpoint (torch.hub's cache name); {other}"))


# --------------------------------------------------------------------------- models
_LOCK = threading.RLock()  # the embedding memo below
_EMBEDS: OrderedDict[tuple, np.ndarray] = OrderedDict()


def _model_key(found: Found, device: str) -> tuple:
    st = found.path.stat()
    return (found.arch, str(found.path.resolve()), st.st_size, st.st_mtime_ns, str(device))


@dataclass
class _Clip:
    model: Any
    tokenizer: Any
    size: tuple[int, int]
    mean: tuple[float, ...]
    std: tuple[float, ...]
    interpolation: str
    resize_mode: str
    key: tuple


def load_clip(found: Found) -> _Clip:
    """The open_clip model for ``found`` on the metrics' device (eval mode), once per process;
    the file is checked against its published SHA-256 first."""
    from visphy_plugins.metrics import _torch

    problem = found.problem()
    if problem:
        raise RuntimeError(problem)

    key = _model_key(found, _weights.device())
    return _torch.load_once(key, lambda: _build_clip(found, key))


def _build_clip(found: Found, key: tuple) -> _Clip:
    import open_clip

    from visphy_plugins.metrics import _torch

    try:
        if found.source == "openai":
            from open_clip.openai import load_openai_model

            model = load_openai_model(str(found.path), precision="fp32", device="cpu")
            conv = model.visual.conv1.weight.shape
            if tuple(conv) != (768, 3, 32, 32):
                raise RuntimeError(f"not a ViT-B/32 CLIP (patch embedding {tuple(conv)})")
        else:
            model = open_clip.create_model(found.arch, pretrained=str(found.path),
                                           precision="fp32", device="cpu")
    except Exception as exc:
        raise RuntimeError(f"cannot load {found.path} as open_clip {found.arch}: {exc}") \
            from exc
    model = model.eval().to(_torch.device())
    from open_clip.model import get_model_preprocess_cfg

    cfg = dict(get_model_preprocess_cfg(model) or {})
    size = cfg.get("size", 224)
    size = (size, size) if isinstance(size, int) else tuple(size)
    from open_clip.constants import OPENAI_DATASET_MEAN, OPENAI_DATASET_STD

    return _Clip(model=model, tokenizer=open_clip.get_tokenizer("ViT-B-32"), size=size,
                 mean=tuple(cfg.get("mean", OPENAI_DATASET_MEAN)),
                 std=tuple(cfg.get("std", OPENAI_DATASET_STD)),
                 interpolation=str(cfg.get("interpolation", "bicubic")),
                 resize_mode=str(cfg.get("resize_mode", "shortest")), key=key)


def load_dino(found: Found):
    """The timm DINO ViT for ``found`` on the metrics' device (eval mode), once per process;
    the file is checked against its published SHA-256 first."""
    from visphy_plugins.metrics import _torch

    problem = found.problem()
    if problem:
        raise RuntimeError(problem)

    key = _model_key(found, _weights.device())

    def build():
        import timm

        try:
            model = timm.create_model(found.arch, pretrained=True, num_classes=0,
                                      pretrained_cfg_overlay=dict(file=str(found.path)))
        except Exception as exc:
            raise RuntimeError(f"cannot load {found.path} as timm {found.arch}: {exc}") from exc
        return model.eval().to(_torch.device()), key

    return _torch.load_once(key, build)


# --------------------------------------------------------------------------- preprocessing
def _resize_uint8(frames: np.ndarray, size: tuple[int, int], mode: str):
    """N×H×W×3 uint8 → N×3×h×w uint8 tensor (CPU), resized with torch's antialiased uint8 kernels
    (PIL's resampling, up to rounding)."""
    from visphy_plugins.metrics import _torch

    t = _torch.torch()
    x = t.from_numpy(np.ascontiguousarray(frames[..., :3])).permute(0, 3, 1, 2)
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    return t.nn.functional.interpolate(x.contiguous(memory_format=t.channels_last),
                                       size=tuple(size), mode=mode, align_corners=False,
                                       antialias=True)


def _normalised_input(x, mean: tuple[float, ...], std: tuple[float, ...]):
    from visphy_plugins.metrics import _torch

    t = _torch.torch()
    x = x.to(_torch.device()).float().div_(255.0)
    m = t.tensor(mean, device=x.device, dtype=x.dtype).view(1, 3, 1, 1)
    s = t.tensor(std, device=x.device, dtype=x.dtype).view(1, 3, 1, 1)
    return ((x - m) / s).contiguous()


def clip_preprocess(frames: np.ndarray, clip: _Clip):
    """N×H×W×3 uint8 → N×3×224×224 float32 on the metrics' device: open_clip's transform for the
    model (the shorter side resized, centre crop, normalise) done batched in torch."""
    h, w = frames.shape[1:3]
    th, tw = clip.size
    mode = "bicubic" if clip.interpolation == "bicubic" else "bilinear"
    if clip.resize_mode == "squash":
        new = (th, tw)
    else:  # "shortest" (open_clip's default): torchvision Resize(int) semantics
        short, long = (h, w) if h <= w else (w, h)
        target = min(th, tw)
        new_long = int(target * long / short)
        new = (target, new_long) if h <= w else (new_long, target)
    x = _resize_uint8(frames, new, mode)
    nh, nw = x.shape[-2:]
    top, left = int(round((nh - th) / 2.0)), int(round((nw - tw) / 2.0))
    return _normalised_input(x[..., top:top + th, left:left + tw], clip.mean, clip.std)


def dino_preprocess(frames: np.ndarray):
    """N×H×W×3 uint8 → N×3×224×224 float32 on the metrics' device: the whole frame resized
    (bicubic, antialiased), ImageNet mean/std."""
    x = _resize_uint8(frames, (DINO_SIZE, DINO_SIZE), "bicubic")
    return _normalised_input(x, IMAGENET_MEAN, IMAGENET_STD)


# --------------------------------------------------------------------------- embeddings
def _frame_digest(frame: np.ndarray) -> bytes:
    f = np.ascontiguousarray(frame[..., :3])
    return hashlib.blake2b(f.tobytes(), digest_size=16,
                           person=str(f.shape).encode()[:16]).digest()


def _normalise(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-12)


def embed_frames(frames: np.ndarray, key: tuple, encode) -> np.ndarray:
    """N×D L2-normalised float64 embeddings of ``frames``; each distinct frame is encoded once
    per process (memo keyed by the model's key and the frame's content), in batches."""
    from visphy_plugins.metrics import _torch

    t = _torch.torch()
    digests = [_frame_digest(f) for f in frames]
    have: dict[bytes, np.ndarray] = {}
    with _LOCK:
        for d in digests:
            v = _EMBEDS.get((key, d))
            if v is not None:
                have[d] = v
                _EMBEDS.move_to_end((key, d))
    todo: dict[bytes, int] = {}
    for i, d in enumerate(digests):
        if d not in have and d not in todo:
            todo[d] = i
    if todo:
        idx = list(todo.values())
        out = []
        with t.inference_mode():
            for s in range(0, len(idx), BATCH):
                out.append(encode(frames[idx[s:s + BATCH]]).float().cpu().numpy())
        fresh = dict(zip(todo, _normalise(np.concatenate(out))))
        have.update(fresh)
        with _LOCK:
            for d, v in fresh.items():
                _EMBEDS[(key, d)] = v
            while len(_EMBEDS) > _EMBED_MEMO:
                _EMBEDS.popitem(last=False)
    return np.stack([have[d] for d in digests])


def clip_image_embeddings(frames: np.ndarray, clip: _Clip) -> np.ndarray:
    return embed_frames(frames, ("clip",) + clip.key,
                        lambda f: clip.model.encode_image(clip_preprocess(f, clip)))


def dino_embeddings(frames: np.ndarray, model, key: tuple) -> np.ndarray:
    return embed_frames(frames, ("dino",) + key, lambda f: model(dino_preprocess(f)))


def text_chunks(token_ids: list[int], is_word_end, max_tokens: int = CLIP_CHUNK_TOKENS
                ) -> list[list[int]]:
    """``token_ids`` cut into ⌈n / max_tokens⌉ consecutive chunks of at most ``max_tokens`` (more
    only where the word ends force it), of balanced length: each cut is the word end (a token
    for which ``is_word_end`` holds) nearest to the even split, or the even split itself inside
    a word too long to keep whole. The chunks together are exactly ``token_ids``."""
    import bisect

    n = len(token_ids)
    if n == 0:
        return []
    ends = [i + 1 for i, tok in enumerate(token_ids) if is_word_end(tok)]
    k = math.ceil(n / max_tokens)
    while True:
        cuts = [0]
        for j in range(1, k):
            ideal = round(j * n / k)
            lo, hi = cuts[-1] + 1, min(cuts[-1] + max_tokens, n - 1)
            if lo > hi:
                break
            a, b = bisect.bisect_left(ends, lo), bisect.bisect_right(ends, hi)
            near = ends[a:b]
            cuts.append(min(near, key=lambda e: (abs(e - ideal), e)) if near
                        else min(max(ideal, lo), hi))
        cuts.append(n)
        chunks = [token_ids[a:b] for a, b in zip(cuts, cuts[1:])]
        if all(0 < len(c) <= max_tokens for c in chunks):
            return chunks
        k += 1


def clip_text_embedding(text: str, clip: _Clip) -> np.ndarray | None:
    """The normalised mean of the normalised CLIP embeddings of ``text``'s chunks (None: the text
    has no token)."""
    from visphy_plugins.metrics import _torch

    t = _torch.torch()
    tok = clip.tokenizer
    ids = tok.encode(text)
    decoder = tok.decoder
    chunks = text_chunks(ids, lambda i: decoder[i].endswith("</w>"))
    if not chunks:
        return None
    ctx = tok.context_length
    tokens = t.zeros(len(chunks), ctx, dtype=t.long)
    for k, c in enumerate(chunks):
        row = [tok.sot_token_id, *c, tok.eot_token_id]
        tokens[k, :len(row)] = t.tensor(row, dtype=t.long)
    with t.inference_mode():
        emb = clip.model.encode_text(tokens.to(_torch.device())).float().cpu().numpy()
    return _normalise(_normalise(emb).mean(axis=0))


def sample_indices(n: int, k: int) -> np.ndarray:
    """At most ``k`` of ``range(n)``, evenly spaced, first and last included."""
    if n <= k:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, k)).astype(int))


# --------------------------------------------------------------------------- metrics
class _SemanticMetric(Metric):
    family = "semantic"
    direction = HIGHER
    score_range = (-1.0, 1.0)
    _packages: tuple[str, ...] = ("torch",)

    def found(self) -> Found | None:
        raise NotImplementedError

    def missing_reason(self) -> str:
        raise NotImplementedError

    @property
    def weights(self) -> str:  # type: ignore[override]
        f = self.found()
        return f"{f.label}: {f.path}" if f else self.missing_reason()

    def model_name(self) -> str | None:
        f = self.found()
        return f.label if f else None

    def unavailable_reason(self) -> str | None:
        from visphy_plugins.metrics._torch import missing_packages

        reason = missing_packages(*self._packages)
        if reason:
            return reason
        f = self.found()
        return self.missing_reason() if f is None else f.problem()

    def verified(self) -> Found:
        """The weights, found and checked against their published SHA-256 (else an error with
        the reason)."""
        f = self.found()
        reason = self.missing_reason() if f is None else f.problem()
        if reason:
            raise RuntimeError(reason)
        return f

    def identity(self) -> str:
        f = self.found()
        tag = f"{f.arch}:{f.source}/weights={_weights.digest(f.path)}" if f else "missing"
        return f"{super().identity()}/{tag}"

    def describe(self) -> dict:
        return {**super().describe(), "model": self.model_name()}


class _ClipMetric(_SemanticMetric):
    _packages = ("torch", "open_clip")
    source = CLIP_LAION

    def found(self) -> Found | None:
        return find_clip(self.source)

    def missing_reason(self) -> str:
        return clip_missing(self.source)

    def clip(self) -> _Clip:
        return load_clip(self.verified())


class ClipImg(_ClipMetric):
    name = "clip_img"
    kind = PAIRS
    needs = ("frames",)
    max_pairs = CLIP_MAX_PAIRS

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        clip = self.clip()
        a = clip_image_embeddings(reference, clip)
        b = clip_image_embeddings(generated, clip)
        return np.clip(np.sum(a * b, axis=1), -1.0, 1.0)


class ClipCap(_ClipMetric):
    name = "clip_cap"
    kind = SCENE
    needs = ("frames", "analysis")
    version = "1"

    def identity(self) -> str:
        return (f"{super().identity()}/frames={CLIP_CAP_FRAMES}"
                f"/chunk={CLIP_CHUNK_TOKENS}")

    def compute(self, inp: MetricInput) -> float:
        text = (inp.analysis or "").strip()
        if not text or len(inp.generated) == 0:
            return float("nan")
        clip = self.clip()
        t_emb = clip_text_embedding(text, clip)
        if t_emb is None:
            return float("nan")
        frames = inp.generated[sample_indices(len(inp.generated), CLIP_CAP_FRAMES)]
        i_emb = _normalise(clip_image_embeddings(frames, clip).mean(axis=0))
        return float(np.clip(np.dot(t_emb, i_emb), -1.0, 1.0))


class ClipImgOpenAI(ClipImg):
    name = "clip_img_openai"
    source = CLIP_OPENAI


class ClipCapOpenAI(ClipCap):
    name = "clip_cap_openai"
    source = CLIP_OPENAI


class Dino(_SemanticMetric):
    name = "dino"
    kind = PAIRS
    needs = ("frames",)
    max_pairs = DINO_MAX_PAIRS
    _packages = ("torch", "timm")
    model_arch = DINO_VARIANTS[0][0]  # ViT-B/16, the paper's

    def found(self) -> Found | None:
        return find_dino(self.model_arch)

    def missing_reason(self) -> str:
        return dino_missing(self.model_arch)

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        model, key = load_dino(self.verified())
        a = dino_embeddings(reference, model, key)
        b = dino_embeddings(generated, model, key)
        return np.clip(np.sum(a * b, axis=1), -1.0, 1.0)


class DinoViTS16(Dino):
    name = "dino_vits16"
    model_arch = DINO_VARIANTS[1][0]  # ViT-S/16


@hookimpl
def visphy_register_metrics(register):
    register(ClipImg())
    register(ClipCap())
    register(Dino())
    register(ClipImgOpenAI())
    register(ClipCapOpenAI())
    register(DinoViTS16())
