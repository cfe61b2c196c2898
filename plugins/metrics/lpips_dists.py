"""Learned perceptual distances on aligned frame pairs (family ``perceptual``, kind ``pairs``,
lower is better): LPIPS, ST-LPIPS and DISTS, and the plumbing that loads their networks
(`_Files`, `_torch_load`, `_load_strict`, `_cached_model`, `_NetMetric`).

Models load once per process, cached by weight file and device, and run under
``torch.inference_mode`` on ``metrics.device``. Weights are never downloaded: the files below
are looked up with `visphy_core.api.weights.find` (``metrics.weights_dir``, ``$VISPHY_WEIGHTS``,
``$TORCH_HOME/hub/checkpoints``); a missing file makes the metric unavailable with the reason.
Every file is checked against its published SHA-256 before it is loaded
(`visphy_core.api.weights.check`: torchvision's checkpoints against the hash prefix in their
names, the packaged LPIPS/ST-LPIPS files against the table in `visphy_core.api.weights`): a file
with the right name and the wrong content makes the metric unavailable (``checksum mismatch
(<file>: expected …, got …)``), never a number. Every metric's identity carries the digest of
the files it loaded.

* ``st_lpips`` ↓ [0, ∞): Shift-tolerant LPIPS (Ghildyal & Liu, ECCV 2022), AlexNet
  ``shift_tolerant`` variant, from the ``stlpips-pytorch`` package, which ships the complete net
  (``stlpips_pytorch/weights/vST0.0/alex_shift_tolerant.pth``: backbone and linear layers) — the
  perceptual metric this machine can always compute. A file called ``alex_shift_tolerant.pth``
  in the weight search replaces the packaged one (checked against the same published SHA-256:
  only an identical copy is accepted). Every parameter and buffer is loaded strictly
  (the package itself loads non-strictly). The package imports ``IPython`` and ``torchsummary``
  without using them; where those are absent, empty stand-ins are put in place for the import
  only (and removed right after).
* ``lpips`` ↓ [0, ∞): LPIPS v0.1 with AlexNet (Zhang et al. 2018, "LPIPS (AlexNet)"), the
  ``lpips`` package's architecture (what upstream's ``lpips.LPIPS(net='alex')`` loads):
  torchvision's AlexNet ImageNet backbone ``alexnet-owt-7be5be79.pth`` (the file torchvision
  lists; the older name ``alexnet-owt-4df8aa71.pth``, which it no longer lists, is not accepted)
  from the weight search and the LPIPS v0.1 linear layers the package ships
  (``lpips/weights/v0.1/alex.pth``).
* ``dists`` ↓ [0, 1]: `piq.DISTS` (Ding et al. 2020), a distance (1 − the DISTS similarity):
  torchvision's VGG16 backbone ``vgg16-397923af.pth`` and piq's DISTS α/β ``dists_weights.pt``
  (the files piq would download from torchvision and from its v0.4.1 release), both from the
  weight search. piq publishes no SHA-256 for ``dists_weights.pt`` (it downloads the file
  unchecked): record the one you trust in ``SHA256SUMS`` (`visphy_core.api.weights`), else the
  file is not used. α and β are divided by their joint sum as in DISTS' definition (a no-op for
  piq's file). piq resizes frames whose shorter side exceeds 256 to 256 itself.

Inputs: LPIPS and ST-LPIPS get the frames in [−1, 1] (their convention), DISTS in [0, 1]. Pairs
run in chunks of `CHUNK` (bounded memory on 75-frame 512² clips).

Per-frame work. ST-LPIPS' and LPIPS' normalised net features (``LPIPS.forward`` split at the
difference of the features: `_lpips_features`, `_lpips_combine`) are computed once per
distinct frame and kept in the per-frame cache (`visphy_plugins.metrics._torch.per_frame`;
`visphy_plugins.metrics._pairs` says why frames repeat); per pair only the comparison runs.
The values equal the per-pair computation to 1e-6 (tested on batches with and without
repeated frames). DISTS keeps its per-pair path: its VGG16 features take about 30 MiB per 256²
frame, more memory than a scene's reuse is worth.

Cost and ``max_pairs``. CPU seconds at 512², one torch thread (torch 2.14, this project's 2-core
machines, shared; the lowest of repeated runs of 8 pairs): before, per pair as the package
computed it; now, per distinct frame (once per scene) and per pair:

============  ===========  ====================  ==============================================
metric        before       now: frame + pair     what runs
============  ===========  ====================  ==============================================
``lpips``     0.21         0.10 + 0.007          AlexNet at 512²
``st_lpips``  0.25         0.13 + 0.007          shift-tolerant AlexNet at 256² (1.3–1.6 at 512²)
``dists``     0.9–1.2      unchanged             VGG16 at 256² (piq resizes)
============  ===========  ====================  ==============================================

Defaults (per pairing, evenly spaced; `visphy_plugins.metrics._pairs` explains them): m = 8
for LPIPS and DISTS (`LPIPS_MAX_PAIRS`, `DISTS_MAX_PAIRS`); ST-LPIPS, the costliest offline
metric, runs at `STLPIPS_SIZE` = 256 (its ranking of shifted, recoloured and resized objects at
256² matched 512² at Spearman 0.99 on synthetic scenes, for a quarter of the cost) on m = 4
(`STLPIPS_MAX_PAIRS`). ``metrics.max_pairs.<name>`` overrides (0 or null: every pair), and the
value is recorded in the identity, as ST-LPIPS' working size is.

Fast path, next to the path it replaced (kept as the reference and compared with it
by tests/test_metric_fast_paths.py on 2D- and 3D-like renders):

* ST-LPIPS (bit for bit): the net's weights channels-last (the frames arrive channels-last, so
  oneDNN reordered the weights on every call) and one frame at a time. Its convolutions then
  run at the float32 peak of this machine's cores (≈ 240 GFLOP/s a core, ≈ 10 GFLOP a 256²
  frame): nothing cheaper in float32. **bfloat16, opt-in**: ``VISPHY_STLPIPS_BF16=1`` runs the
  net under bfloat16 autocast (for CPUs with AVX512-BF16 or AMX; elsewhere it is emulated and
  slower), features and the comparison in float32; the identity gains ``/bf16`` (cached scores
  and per-frame features are kept apart). Measured on 15 scenes of the sub split: 0.64× the
  CPU time, |Δ| ≤ 4.8e-4 on values up to 0.24 (≤ 0.7 % of values above 1e-3); stated
  tolerance 1e-3. Default: float32.
"""
# size: one weight-loading path (_Files, _load_strict, _NetMetric) shared by LPIPS/ST-LPIPS/DISTS

from __future__ import annotations

import importlib.util
import os
import sys
import types
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from visphy_core.api import weights as _weights
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import LOWER, PAIRS, Metric
from visphy_plugins.metrics import _torch
from visphy_plugins.metrics._pairs import CHUNK, split_frames

#: ``max_pairs`` defaults (per pairing; see the module docstring for the costs behind them).
LPIPS_MAX_PAIRS = 8
STLPIPS_MAX_PAIRS = 4
DISTS_MAX_PAIRS = 8
#: ST-LPIPS' working resolution (shorter side, area resize; None: the frames as they are).
STLPIPS_SIZE = 256
#: ``1``: ST-LPIPS' net runs in bfloat16 (opt-in; default float32): see the module docstring
STLPIPS_BF16_ENV = "VISPHY_STLPIPS_BF16"

ALEXNET_FILES = ("alexnet-owt-7be5be79.pth",)
VGG16_FILES = ("vgg16-397923af.pth",)
DISTS_FILES = ("dists_weights.pt",)
STLPIPS_FILES = ("alex_shift_tolerant.pth",)


# --------------------------------------------------------------------------- loaded models
@dataclass(frozen=True)
class _Files:
    """The weight files a learned metric loads (None where one is missing) and their keys in
    `visphy_core.api.weights.expected` (None: the file's name)."""

    paths: tuple[Path | None, ...]
    keys: tuple[str | None, ...] = ()

    @property
    def complete(self) -> bool:
        return all(p is not None for p in self.paths)

    def problem(self) -> str | None:
        """None when every file hashes to its published SHA-256; else the first mismatch."""
        keys = self.keys or (None,) * len(self.paths)
        for path, key in zip(self.paths, keys):
            problem = _weights.check(path, key)
            if problem:
                return problem
        return None

    def key(self) -> tuple:
        out = []
        for p in self.paths:
            st = p.stat()
            out.append((str(p.resolve()), st.st_size, st.st_mtime_ns))
        return tuple(out)

    def digest(self) -> str:
        return "+".join(_weights.digest(p) for p in self.paths)


def _torch_load(path: Path) -> dict:
    t = _torch.torch()
    obj = t.load(str(path), map_location="cpu", weights_only=True)
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict):
        raise RuntimeError(f"{path}: not a state dict")
    return obj


def _load_strict(module, state: dict, what: str, aliases: Callable[[str], str] = lambda k: k
                 ) -> None:
    """Every parameter and buffer of ``module`` from ``state`` (key ``aliases(name)``), with
    matching shapes; nothing left out."""
    t = _torch.torch()
    own = module.state_dict()
    missing, wrong = [], []
    full = {}
    for name, value in own.items():
        src = aliases(name)
        if src not in state:
            missing.append(src)
            continue
        if tuple(state[src].shape) != tuple(value.shape):
            wrong.append(f"{src} {tuple(state[src].shape)} != {tuple(value.shape)}")
            continue
        full[name] = state[src]
    if missing or wrong:
        raise RuntimeError(f"{what}: missing {missing[:6]}{'…' if len(missing) > 6 else ''}"
                           f"{'; wrong shapes ' + ', '.join(wrong[:4]) if wrong else ''}")
    with t.no_grad():
        module.load_state_dict(full, strict=True)


def _cached_model(kind: str, files: _Files, build: Callable[[], Any]):
    def frozen():
        model = build().eval().to(_torch.device())
        for p in model.parameters():
            p.requires_grad_(False)
        return model

    return _torch.load_once((kind, files.key(), _weights.device()), frozen)


class _NetMetric(Metric):
    """A learned distance: lower is better, model loaded once per process."""

    family = "perceptual"
    kind = PAIRS
    direction = LOWER
    score_range = (0.0, float("inf"))
    packages: tuple[str, ...] = ("torch",)
    value_range: tuple[float, float] = (-1.0, 1.0)
    #: working resolution: frames whose shorter side is longer are area-resized to it first
    size: int | None = None

    # subclasses: files() / missing_reason() / build(files) / forward(model, x, y)
    def files(self) -> _Files:  # pragma: no cover - abstract
        raise NotImplementedError

    def missing_reason(self, files: _Files) -> str:  # pragma: no cover - abstract
        raise NotImplementedError

    def unavailable_reason(self) -> str | None:
        reason = _torch.missing_packages(*self.packages)
        if reason:
            return reason
        files = self.files()
        return files.problem() if files.complete else self.missing_reason(files)

    def identity(self) -> str:
        files = self.files()
        ident = super().identity()
        if self.size is not None:
            ident += f"/size={self.size}"
        if self.precision() != "fp32":
            ident += f"/{self.precision()}"
        return f"{ident}/weights={files.digest()}" if files.complete else ident

    def precision(self) -> str:
        """What the net's features are computed in: ``fp32`` (the default)."""
        return "fp32"

    def model(self):
        files = self.files()
        reason = files.problem() if files.complete else self.missing_reason(files)
        if reason:
            raise RuntimeError(reason)
        return _cached_model(self.name, files, lambda: self.build(files))

    def _tensor(self, frames: np.ndarray):
        """uint8 frames → N×3×H×W in ``value_range``, area-resized so the shorter side is
        ``size`` when it is longer (``size`` None: as they are)."""
        t = _torch.torch()
        x = _torch.to_tensor(frames)
        h, w = x.shape[-2:]
        if self.size is not None and min(h, w) > self.size:
            f = self.size / min(h, w)
            x = t.nn.functional.interpolate(x, size=(max(1, round(h * f)), max(1, round(w * f))),
                                            mode="area")
        lo, hi = self.value_range
        return x * (hi - lo) + lo if (lo, hi) != (0.0, 1.0) else x

    #: the net's features are computed once per distinct frame (`features`, `combine`);
    #: False: ``forward(model, x, y)`` on each chunk of pairs
    per_frame_features = False

    def features(self, model, x) -> list:  # pragma: no cover - abstract
        """Per frame of the batch ``x`` (``_tensor``'s): what ``forward`` computes of it alone."""
        raise NotImplementedError

    def combine(self, model, fx: tuple, fy: tuple):  # pragma: no cover - abstract
        """``forward``'s value for one pair from its frames' `features` (batches of one)."""
        raise NotImplementedError

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        t = _torch.torch()
        model = self.model()
        out = []
        with t.inference_mode():
            ns = (self.name, self.files().key(), str(_torch.device()), self.size,
                  self.precision())

            def feats(frames):
                return self.features(model, self._tensor(frames))

            for s in range(0, len(reference), CHUNK):
                if self.per_frame_features:
                    f_ref = _torch.per_frame(reference[s:s + CHUNK], ns + ("reference",), feats)
                    f_gen = _torch.per_frame(generated[s:s + CHUNK], ns + ("generated",), feats)
                    value = t.cat([self.combine(model, fx, fy).reshape(-1)
                                   for fx, fy in zip(f_ref, f_gen)])
                else:
                    x = self._tensor(reference[s:s + CHUNK])
                    y = self._tensor(generated[s:s + CHUNK])
                    value = self.forward(model, x, y)
                out.append(value.double().cpu().numpy().reshape(-1))
        return np.concatenate(out) if out else np.zeros(0)


def _lpips_features(model, x, normalize_tensor) -> list[tuple]:
    """What ``LPIPS.forward(in0, in1)`` (lpips and stlpips-pytorch alike) computes of ``in0``
    alone: the input scaling (v0.1), the net's five feature maps, each unit-normalised over its
    channels; per frame, its own copies."""
    inp = model.scaling_layer(x) if model.version == "0.1" else x
    outs = model.net.forward(inp)
    return split_frames(*[normalize_tensor(o) for o in outs])


def _lpips_combine(model, fx: tuple, fy: tuple):
    """The rest of ``LPIPS.forward`` (lpips=True, spatial=False): per layer the squared
    difference of the normalised features, its linear layer, the spatial mean; their sum."""
    val = None
    for kk in range(model.L):
        diff = (fx[kk] - fy[kk]) ** 2
        res = model.lins[kk](diff).mean([2, 3], keepdim=True)
        val = res if val is None else val + res
    return val


# ----------------------------------------------------------------------------- ST-LPIPS
def _import_stlpips():
    """``stlpips_pytorch.stlpips``; its unused ``IPython``/``torchsummary`` imports get empty
    stand-ins for the import only, where those packages are not installed."""
    if "stlpips_pytorch.stlpips" in sys.modules:
        return sys.modules["stlpips_pytorch.stlpips"]
    stubs = []
    for name, attr in (("IPython", "embed"), ("torchsummary", "summary")):
        if name not in sys.modules and importlib.util.find_spec(name) is None:
            stub = types.ModuleType(name)
            setattr(stub, attr, lambda *a, **k: None)
            sys.modules[name] = stub
            stubs.append(name)
    try:
        from stlpips_pytorch import stlpips
    finally:
        for name in stubs:
            sys.modules.pop(name, None)
    return stlpips


STLPIPS_KEY = "stlpips_pytorch/weights/vST0.0/alex_shift_tolerant.pth"
LPIPS_LINEAR_KEY = "lpips/weights/v0.1/alex.pth"


def stlpips_packaged_file(net: str = "alex") -> Path | None:
    spec = importlib.util.find_spec("stlpips_pytorch")
    if spec is None or not spec.submodule_search_locations:
        return None
    p = Path(list(spec.submodule_search_locations)[0]) / "weights" / "vST0.0" \
        / f"{net}_shift_tolerant.pth"
    return p if p.is_file() else None


def _lins_alias(name: str) -> str:
    # ``lins`` is a ModuleList over lin0..lin4 (the same modules): its names are aliases
    if name.startswith("lins."):
        k, rest = name[len("lins."):].split(".", 1)
        return f"lin{k}.{rest}"
    return name


class STLPIPS(_NetMetric):
    name = "st_lpips"
    packages = ("torch", "torchvision", "stlpips_pytorch")
    max_pairs = STLPIPS_MAX_PAIRS
    size = STLPIPS_SIZE

    @property
    def weights(self) -> str:  # type: ignore[override]
        f = self.files().paths[0]
        return ("ST-LPIPS AlexNet shift-tolerant net, backbone + linear layers: "
                f"{f or 'stlpips_pytorch/weights/vST0.0/alex_shift_tolerant.pth'} "
                "(stlpips-pytorch)")

    def files(self) -> _Files:
        return _Files((_weights.find(*STLPIPS_FILES) or stlpips_packaged_file("alex"),),
                      (STLPIPS_KEY,))

    def missing_reason(self, files: _Files) -> str:
        return _weights.missing(
            "ST-LPIPS AlexNet shift-tolerant net", list(STLPIPS_FILES),
            extra="the stlpips-pytorch package ships it "
                  "(stlpips_pytorch/weights/vST0.0/alex_shift_tolerant.pth); reinstall it")

    def build(self, files: _Files):
        stlpips = _import_stlpips()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = stlpips.LPIPS(net="alex", variant="shift_tolerant", pretrained=False,
                                  verbose=False)
        _load_strict(model, _torch_load(files.paths[0]), f"ST-LPIPS ({files.paths[0]})",
                     _lins_alias)
        # the frames come channels-last (`_tensor`), so oneDNN runs channels-last: weights in
        # that layout are not reordered on every call (same values, bit for bit)
        return model.to(memory_format=_torch.torch().channels_last)

    def forward(self, model, x, y):
        return model(x, y)

    per_frame_features = True

    def precision(self) -> str:
        """``bf16`` when ``$VISPHY_STLPIPS_BF16`` is 1 (opt-in, `STLPIPS_BF16_ENV`), else
        ``fp32``."""
        value = os.environ.get(STLPIPS_BF16_ENV, "").strip().lower()
        if value in ("", "0", "false", "no", "off"):
            return "fp32"
        if value in ("1", "true", "yes", "on"):
            return "bf16"
        raise ValueError(f"${STLPIPS_BF16_ENV} must be 0 or 1, not {value!r}")

    def features(self, model, x) -> list:
        """One frame at a time (channels-last): a frame's activations stay in the CPU's caches
        (measured: about 0.75× the CPU time per frame of a batch of four; the same values, bit
        for bit). With `precision` ``bf16`` the net runs under bfloat16 autocast and its
        normalised features are returned as float32."""
        from stlpips_pytorch import utils

        t = _torch.torch()
        x = x.contiguous(memory_format=t.channels_last)
        if self.precision() == "fp32":
            return [f for i in range(len(x))
                    for f in _lpips_features(model, x[i:i + 1], utils.normalize_tensor)]
        out = []
        for i in range(len(x)):
            with t.autocast(x.device.type, dtype=t.bfloat16):
                feats = _lpips_features(model, x[i:i + 1], utils.normalize_tensor)
            out += [tuple(f.float() for f in frame) for frame in feats]
        return out

    def combine(self, model, fx: tuple, fy: tuple):
        return _lpips_combine(model, fx, fy)


# ----------------------------------------------------------------------------- LPIPS
def lpips_linear_file(net: str = "alex") -> Path | None:
    spec = importlib.util.find_spec("lpips")
    if spec is None or not spec.submodule_search_locations:
        return None
    p = Path(list(spec.submodule_search_locations)[0]) / "weights" / "v0.1" / f"{net}.pth"
    return p if p.is_file() else None


class LPIPS(_NetMetric):
    name = "lpips"
    packages = ("torch", "torchvision", "lpips")
    max_pairs = LPIPS_MAX_PAIRS

    @property
    def weights(self) -> str:  # type: ignore[override]
        backbone, lin = self.files().paths
        return (f"AlexNet ImageNet backbone: {backbone or ' or '.join(ALEXNET_FILES)} (torchvision)"
                f" + LPIPS v0.1 linear layers: {lin or 'lpips/weights/v0.1/alex.pth'} (lpips)")

    def files(self) -> _Files:
        return _Files((_weights.find(*ALEXNET_FILES), lpips_linear_file("alex")),
                      (None, LPIPS_LINEAR_KEY))

    def missing_reason(self, files: _Files) -> str:
        if files.paths[0] is None:
            return _weights.missing(
                "torchvision's AlexNet ImageNet weights (LPIPS backbone)", list(ALEXNET_FILES),
                extra=f"{ALEXNET_FILES[0]} is what torchvision.models.alexnet("
                      "weights='IMAGENET1K_V1') downloads; the LPIPS v0.1 linear layers come "
                      "with the lpips package")
        return ("LPIPS v0.1 linear layers not found: lpips/weights/v0.1/alex.pth ships with the "
                "lpips package; reinstall it (pip install lpips==0.1.4)")

    def build(self, files: _Files):
        import lpips

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = lpips.LPIPS(net="alex", version="0.1", pretrained=False, pnet_rand=True,
                                verbose=False)
        backbone = _torch_load(files.paths[0])
        lins = _torch_load(files.paths[1])
        # the backbone's slices keep torchvision's layer numbers: net.sliceK.<i>.* ↔ features.<i>.*
        state = dict(lins)
        for name in model.net.state_dict():
            _, idx, rest = name.split(".", 2)
            state[f"net.{name}"] = backbone.get(f"features.{idx}.{rest}")
        state = {k: v for k, v in state.items() if v is not None}
        buffers = {k: v for k, v in model.state_dict().items() if k.startswith("scaling_layer.")}
        state.update(buffers)  # the fixed input shift/scale constants
        _load_strict(model, state, f"LPIPS (AlexNet {files.paths[0]}, linear {files.paths[1]})",
                     _lins_alias)
        return model

    def forward(self, model, x, y):
        return model(x, y)

    per_frame_features = True

    def features(self, model, x) -> list:
        import lpips

        return _lpips_features(model, x, lpips.normalize_tensor)

    def combine(self, model, fx: tuple, fy: tuple):
        return _lpips_combine(model, fx, fy)


# ----------------------------------------------------------------------------- DISTS
# piq's VGG16 layer names → torchvision ``features`` indices (relu1_2 … relu5_3)
_DISTS_LAYERS = ("3", "8", "15", "22", "29")
_DISTS_CHANNELS = (3, 64, 128, 256, 512, 512)


class DISTS(_NetMetric):
    name = "dists"
    packages = ("torch", "torchvision", "piq")
    max_pairs = DISTS_MAX_PAIRS
    score_range = (0.0, 1.0)
    value_range = (0.0, 1.0)

    @property
    def weights(self) -> str:  # type: ignore[override]
        vgg, ab = self.files().paths
        return (f"VGG16 ImageNet backbone: {vgg or VGG16_FILES[0]} (torchvision) + DISTS "
                f"alpha/beta: {ab or DISTS_FILES[0]} (piq)")

    def files(self) -> _Files:
        return _Files((_weights.find(*VGG16_FILES), _weights.find(*DISTS_FILES)))

    def missing_reason(self, files: _Files) -> str:
        absent = [ns[0] for p, ns in zip(files.paths, (VGG16_FILES, DISTS_FILES)) if p is None]
        return _weights.missing(
            "DISTS weights (torchvision VGG16 + piq's DISTS alpha/beta)", [" and ".join(absent)],
            extra="vgg16-397923af.pth is what torchvision.models.vgg16(weights='IMAGENET1K_V1') "
                  "downloads; dists_weights.pt is piq's v0.4.1 release file "
                  "(github.com/photosynthesis-team/piq/releases/download/v0.4.1/dists_weights.pt)")

    def build(self, files: _Files):
        import piq
        from piq.perceptual import IMAGENET_MEAN, IMAGENET_STD, ContentLoss

        t = _torch.torch()
        try:  # the ``features`` part alone (vgg16().features, without building the classifier)
            from torchvision.models.vgg import cfgs, make_layers

            features = make_layers(cfgs["D"], batch_norm=False)
        except ImportError:  # pragma: no cover - a torchvision without these helpers
            from torchvision.models import vgg16

            features = vgg16(weights=None).features
        backbone = _torch_load(files.paths[0])
        _load_strict(features, backbone, f"DISTS VGG16 ({files.paths[0]})",
                     lambda k: f"features.{k}")
        ab = _torch_load(files.paths[1])
        if "alpha" not in ab or "beta" not in ab:
            raise RuntimeError(f"{files.paths[1]}: no 'alpha'/'beta' (not a DISTS weight file)")
        alpha, beta = ab["alpha"].float(), ab["beta"].float()
        n = sum(_DISTS_CHANNELS)
        if alpha.numel() != n or beta.numel() != n:
            raise RuntimeError(f"{files.paths[1]}: alpha/beta of {alpha.numel()}/{beta.numel()} "
                               f"values, DISTS has {n}")
        total = alpha.sum() + beta.sum()
        alpha, beta = alpha.view(1, n, 1, 1) / total, beta.view(1, n, 1, 1) / total
        layer_weights = list(t.split(alpha, list(_DISTS_CHANNELS), dim=1)) \
            + list(t.split(beta, list(_DISTS_CHANNELS), dim=1))

        class _OfflineDISTS(piq.DISTS):
            """piq.DISTS built from given weights instead of downloaded ones."""

            def __init__(self):  # noqa: D401 - skips piq.DISTS.__init__'s downloads
                ContentLoss.__init__(self, feature_extractor=features, layers=_DISTS_LAYERS,
                                     weights=layer_weights, replace_pooling=True,
                                     reduction="none", mean=IMAGENET_MEAN, std=IMAGENET_STD,
                                     normalize_features=False,
                                     allow_layers_weights_mismatch=True)

        return _OfflineDISTS()

    def forward(self, model, x, y):
        return model(x, y)


@hookimpl
def visphy_register_metrics(register):
    register(LPIPS())
    register(STLPIPS())
    register(DISTS())
