"""Perceptual metrics on aligned frame pairs (family ``perceptual``, kind ``pairs``).

Weight-free, equal to piq 0.8's functions on [0, 1] RGB tensors with ``data_range=1``:

* ``ms_ssim`` ↑ [0, 1]: `piq.multi_scale_ssim` (5 scales, 11-tap Gaussian σ 1.5, Wang 2003
  weights), re-implemented with separable OpenCV float32 filters (`ms_ssim_pair`: piq's
  valid-mode windows, its replicate padding and 2×2 average pooling between scales, the cs
  means at scales 1–4 and the SSIM mean at scale 5, relu, the weights' product, the mean over
  R, G, B last). It equals piq's float32 value within 1e-5 (a few 1e-6 on rendered frames:
  piq's own float32 rounding; the value here is closer to piq's float64 result). Frames need
  at least 161 px a side; smaller frames give NaN (recorded as None). Needs neither torch nor
  piq.
* ``fsim`` ↑ [0, 1]: `piq.fsim` with its default ``chromatic=True`` (FSIMc). piq average-pools
  by ``round(min(H, W) / 256)`` first (2 at 512²); nothing is pre-downsampled here, so the value
  is piq's on the full-size frames.
* ``vsi`` ↑ [0, 1]: `piq.vsi` (its saliency map is computed at 256² inside piq; the frames are
  passed at full size: VSI pads before pooling, so pre-downsampling would change its value).

FSIM and VSI run piq's code split in two (`_PiqMetric`): what piq computes of each image alone
(FSIM: YIQ, phase congruency, gradient magnitude; VSI: SDSP saliency, LMN, gradient magnitude,
padded and pooled), with piq's own functions, and piq's remaining per-pair operations on them.
FSIM's phase congruency is piq's, bit for bit, with the log-Gabor bank and the terms piq derives
from the filters alone built once per image size (piq rebuilds them, 16 inverse FFTs at 256²,
on every call). Values equal direct piq calls to 1e-6.

Learned (models load once per process, cached by weight file and device, and run under
``torch.inference_mode`` on ``metrics.device``). Weights are never downloaded: the files below
are looked up with `visphy_core.api.weights.find` (``metrics.weights_dir``, ``$VISPHY_WEIGHTS``,
``$TORCH_HOME/hub/checkpoints``); a missing file makes the metric unavailable with the reason.
Every file is checked against its published SHA-256 before it is loaded
(`visphy_core.api.weights.check`: torchvision's checkpoints against the hash prefix in their
names,
the packaged LPIPS/ST-LPIPS files against the table in `visphy_core.api.weights`): a file with
the right name and the wrong content makes the metric unavailable (``checksum mismatch (<file>:
expected …, got …)``), never a number. Every metric's identity carries the digest of the files
it loaded.

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

Inputs: LPIPS and ST-LPIPS get the frames in [−1, 1] (their convention), DISTS and the piq
metrics in [0, 1]. Pairs run in chunks of `CHUNK` (bounded memory on 75-frame 512² clips).

Per-frame work. The scorer asks for a scene's pairs one pairing at a time (unaligned, aligned,
paper), and the same reference and generated frames come back in each (and held frames within
one). What a metric computes of one frame alone — FSIM's and VSI's per-image maps, ST-LPIPS'
and LPIPS' normalised net features (``LPIPS.forward`` split at the difference of the features:
`_lpips_features`, `_lpips_combine`) — is computed once per distinct frame and kept in the
per-frame cache (`visphy_plugins.metrics._torch.per_frame`); per pair only the comparison runs.
The values equal the per-pair computation to 1e-6 (tested on batches with and without
repeated frames). DISTS keeps its per-pair path: its VGG16 features take about 30 MiB per 256²
frame, more memory than a scene's reuse is worth.

Cost and ``max_pairs``. CPU seconds at 512², one torch thread (torch 2.14, this project's 2-core
machines, shared; the lowest of repeated runs of 8 pairs): before, per pair as piq or the
package computed it; now, per distinct frame (once per scene) and per pair:

============  ===========  ====================  ==============================================
metric        before       now: frame + pair     what runs
============  ===========  ====================  ==============================================
``ms_ssim``   0.09–0.12    — + 0.016             OpenCV separable filters, 5 scales from 512²
                                                 (piq: full 11×11 convolutions in torch)
``vsi``       0.048        0.023 + 0.005         piq, saliency at 256², similarity at 256²
``fsim``      0.074        0.027 + 0.004         piq, phase congruency at 256² (pooled by 2)
``lpips``     0.21         0.10 + 0.007          AlexNet at 512²
``st_lpips``  0.25         0.13 + 0.007          shift-tolerant AlexNet at 256² (1.3–1.6 at 512²)
``dists``     0.9–1.2      unchanged             VGG16 at 256² (piq resizes)
============  ===========  ====================  ==============================================

Fast paths (issue 22), each next to the path it replaced (kept as the reference and compared
with it by tests/test_metric_fast_paths.py on 2D- and 3D-like renders):

* FSIM (bit for bit): one frame at a time (a batch of four frames' 64 filter responses, 32 MiB,
  leave the CPU's caches); the ×255 scaling by a look-up table and the 2×2 pooling by OpenCV's
  area resize (`_fsim_input`: torch's floats exactly); the phase congruency one orientation at
  a time into reused buffers, the filter bank converted to complex once, the noise median by
  numpy's selection (`_phase_congruency_fast`: the same operations in the same order as
  `_phase_congruency`, the same median element).
  Previous path: `FSIM._reference_frame_features`.
* VSI (bit for bit): one frame at a time; the scalings by look-up tables; piq's SDSP with its
  log-Gabor filter and centre-bias map built once (`_sdsp`); the LMN channels' replicate pad
  and 2×2 pooling by OpenCV (the same floats as torch's on this layout). Previous path:
  `VSI._reference_frame_features`.
* ST-LPIPS (bit for bit): the net's weights channels-last (the frames arrive channels-last, so
  oneDNN reordered the weights on every call) and one frame at a time. Its convolutions then
  run at the float32 peak of this machine's cores (≈ 240 GFLOP/s a core, ≈ 10 GFLOP a 256²
  frame): nothing cheaper in float32. **bfloat16, opt-in**: ``VISPHY_STLPIPS_BF16=1`` runs the
  net under bfloat16 autocast (for CPUs with AVX512-BF16 or AMX; elsewhere it is emulated and
  slower), features and the comparison in float32; the identity gains ``/bf16`` (cached scores
  and per-frame features are kept apart). Measured on 15 scenes of the sub split: 0.64× the
  CPU time, |Δ| ≤ 4.8e-4 on values up to 0.24 (≤ 0.7 % of values above 1e-3); stated
  tolerance 1e-3. Default: float32.

MS-SSIM's per-frame share (two of five blurs per scale) is not cached: its 12 MiB of maps per
512² frame cost about as much in fresh memory as they would save on the frames a 2D scene
reuses. With two torch threads the wall time is at best about half the CPU time on idle cores,
and much worse than one thread where other processes keep the cores busy
(`_torch.default_threads`, ``$VISPHY_TORCH_THREADS``).

The scorer computes each distinct pair of a scene once for the three pairings; with
``max_pairs`` m per pairing a 17-frame scene has about 7 (m 4), 12 (m 8) or 17 (every pair)
distinct pairs at offset 0, 10 / 18 / 32 when the aligned offset is not 0, and a 75-frame scene
7–8 / 12–20 / 75–148. The frames are fewer than twice the pairs: on the benchmark's 2D scenes
(aligned offset 2) 11 pairs use 17 distinct frames (m 4) and 20 pairs 30 (m 8); on its 3D
scenes (offset 0) each frame is used once. Defaults: m = 8 (`PIQ_MAX_PAIRS`, `LPIPS_MAX_PAIRS`,
`DISTS_MAX_PAIRS`) keeps the paper pairing of a 2D scene whole (every 3rd of 17 frames: 6 pairs)
while bounding 3D scenes; ST-LPIPS, the costliest offline metric, runs at `STLPIPS_SIZE` = 256
(its ranking of shifted, recoloured and resized objects at 256² matched 512² at Spearman 0.99
on synthetic scenes, for a quarter of the cost) on m = 4 (`STLPIPS_MAX_PAIRS`). The sampled
pairs are evenly spaced in time, first and last included; ``metrics.max_pairs.<name>``
overrides (0 or null: every pair), and the value is recorded in the identity, as ST-LPIPS'
working size is.
"""

from __future__ import annotations

import importlib.util
import inspect
import math
import os
import sys
import types
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from visphy_core.api import weights as _weights
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import HIGHER, LOWER, PAIRS, Metric
from visphy_plugins.metrics import _torch

#: Pairs per forward pass.
CHUNK = 4
#: ``max_pairs`` defaults (per pairing; see the module docstring for the costs behind them).
PIQ_MAX_PAIRS = 8
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
MS_SSIM_MIN_SIZE = 161  # (11 - 1) * 2 ** 4 + 1


# --------------------------------------------------------------------------- MS-SSIM
_MS_TAPS = np.exp(-(np.arange(11) - 5.0) ** 2 / (2 * 1.5**2))
#: piq's 11×11 Gaussian window (σ 1.5) is the outer product of this normalised 1-D kernel
_MS_KERNEL = (_MS_TAPS / _MS_TAPS.sum()).astype(np.float32)
#: Wang et al. 2003's scale weights, as piq uses them
MS_SSIM_WEIGHTS = np.array([0.0448, 0.2856, 0.3001, 0.2363, 0.1333])
_MS_C1, _MS_C2 = np.float32(0.01**2), np.float32(0.03**2)


def _halve(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """piq's step to the next scale: when either side is odd, one row and one column of edge
    values added at the top and left (``F.pad(..., [p, 0, p, 0], 'replicate')``), then 2×2
    means (``avg_pool2d(2)``, an odd last row or column dropped). OpenCV's area resize of the
    even part is that block mean, bit for bit."""
    p = max(x.shape[0] % 2, x.shape[1] % 2)
    if p:
        x = cv2.copyMakeBorder(x, p, 0, p, 0, cv2.BORDER_REPLICATE)
    h, w = x.shape[0] // 2, x.shape[1] // 2
    return cv2.resize(x[:2 * h, :2 * w], (w, h), dst=out, interpolation=cv2.INTER_AREA)


def _channel_means(m: np.ndarray) -> np.ndarray:
    """Per-channel means of an H×W×3 float32 map, summed in float64."""
    return np.array(cv2.sumElems(m)[:3]) / (m.shape[0] * m.shape[1])


class _MsSsimScale:
    """The work arrays of one scale (allocated once per batch of pairs: fresh multi-megabyte
    arrays for every operation cost more in page faults than the arithmetic)."""

    def __init__(self, h: int, w: int):
        r = 5
        full = lambda: np.empty((h, w, 3), np.float32)  # noqa: E731
        self.x, self.y, self.prod = full(), full(), full()
        # blurred x, y, x², y², xy over the whole image; the valid part is kept
        self.blurred = [full() for _ in range(5)]
        self.valid = [b[r:h - r, r:w - r] for b in self.blurred]
        vh, vw = h - 2 * r, w - 2 * r
        self.t = [np.empty((vh, vw, 3), np.float32) for _ in range(3)]

    def blur(self, src: np.ndarray, k: int) -> None:
        cv2.sepFilter2D(src, -1, _MS_KERNEL, _MS_KERNEL, dst=self.blurred[k],
                        borderType=cv2.BORDER_REFLECT)

    def means(self, last: bool) -> np.ndarray:
        """piq's ``_ssim_per_channel`` on ``x``, ``y``: the per-channel mean of the cs map
        (``last``: of the SSIM map), with piq's float32 operations in piq's order."""
        x, y, p = self.x, self.y, self.prod
        self.blur(x, 0)
        self.blur(y, 1)
        np.multiply(x, x, out=p)
        self.blur(p, 2)
        np.multiply(y, y, out=p)
        self.blur(p, 3)
        np.multiply(x, y, out=p)
        self.blur(p, 4)
        mx, my, sxx, syy, sxy = self.valid
        mxx, myy, mxy = self.t
        np.multiply(mx, mx, out=mxx)
        np.multiply(my, my, out=myy)
        np.multiply(mx, my, out=mxy)
        sxx -= mxx  # σx² = conv(x²) − μx², …
        syy -= myy
        sxy -= mxy
        cs = sxy  # cs = (2σxy + C2) / (σx² + σy² + C2)
        cs *= np.float32(2.0)
        cs += _MS_C2
        sxx += syy
        sxx += _MS_C2
        cs /= sxx
        if not last:
            return _channel_means(cs)
        ss = mxy  # ss = (2μxμy + C1) / (μx² + μy² + C1) · cs
        ss *= np.float32(2.0)
        ss += _MS_C1
        mxx += myy
        mxx += _MS_C1
        ss /= mxx
        ss *= cs
        return _channel_means(ss)


def _ms_ssim_scales(h: int, w: int) -> list[_MsSsimScale]:
    shapes = [(h, w)]
    for _ in range(len(MS_SSIM_WEIGHTS) - 1):
        h, w = shapes[-1]
        p = max(h % 2, w % 2)
        shapes.append(((h + p) // 2, (w + p) // 2))
    return [_MsSsimScale(*hw) for hw in shapes]


def ms_ssim_pair(a: np.ndarray, b: np.ndarray, scales: list[_MsSsimScale] | None = None
                 ) -> float:
    """``piq.multi_scale_ssim(x, y, data_range=1.0, reduction='none')`` of one pair of H×W×3
    uint8 frames (x = frame / 255, float32), computed with separable OpenCV filters
    (``scales``: work arrays from `_ms_ssim_scales`, reused across pairs of one size).

    Per scale and channel, as piq: valid-mode Gaussian moments; the contrast-structure mean
    ``cs`` at the first four scales and the SSIM mean at the fifth (the luminance term times the
    cs map), with piq's float32 operations in piq's order; each mean clipped at 0 (``relu``),
    raised to its scale weight and multiplied over the scales; then the mean over the channels.
    Means are summed in float64 (piq: float32), so the value is within a few 1e-6 of piq's and
    closer to piq's own float64 result than piq's float32 result is."""
    a, b = np.asarray(a)[..., :3], np.asarray(b)[..., :3]
    scales = scales or _ms_ssim_scales(*a.shape[:2])
    first = scales[0]
    first.x[...] = a
    first.x /= np.float32(255.0)
    first.y[...] = b
    first.y /= np.float32(255.0)
    per_scale = []
    for level, sc in enumerate(scales):
        if level:
            _halve(scales[level - 1].x, out=sc.x)
            _halve(scales[level - 1].y, out=sc.y)
        per_scale.append(sc.means(last=level == len(scales) - 1))
    values = np.maximum(np.stack(per_scale), 0.0)  # scales × channels
    return float(np.prod(values ** MS_SSIM_WEIGHTS[:, None], axis=0).mean())


class MSSSIM(Metric):
    name = "ms_ssim"
    family = "perceptual"
    kind = PAIRS
    direction = HIGHER
    score_range = (0.0, 1.0)
    max_pairs = PIQ_MAX_PAIRS

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        if min(np.shape(reference)[1:3]) < MS_SSIM_MIN_SIZE:
            return np.full(len(reference), np.nan)
        scales = _ms_ssim_scales(*np.shape(reference)[1:3]) if len(reference) else None
        return np.array([ms_ssim_pair(a, b, scales) for a, b in zip(reference, generated)])


# --------------------------------------------------------------------------- FSIM, VSI (piq)
class _PiqMetric(Metric):
    """A piq metric split into what each frame needs alone (`frame_features`, piq's own
    functions on a batch of frames) and what each pair needs (`combine`, piq's remaining
    operations on the pairs' stacked features): the features are computed once per distinct
    frame (`_torch.per_frame`), and the values are piq's."""

    family = "perceptual"
    kind = PAIRS
    direction = HIGHER
    score_range = (0.0, 1.0)
    max_pairs = PIQ_MAX_PAIRS

    def unavailable_reason(self) -> str | None:
        return _torch.missing_packages("torch", "piq")

    def frame_features(self, frames: np.ndarray) -> list[tuple]:  # pragma: no cover - abstract
        raise NotImplementedError

    def combine(self, fx: tuple, fy: tuple):  # pragma: no cover - abstract
        """piq's value for one pair from its frames' `frame_features` (batches of one)."""
        raise NotImplementedError

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        """One torch thread, whatever the process's count: per frame and per pair this is
        hundreds of operations on 256² maps, too small to share (with two threads on this
        project's two shared cores a scene's FSIM and VSI measured 2–10× the CPU seconds of
        one thread, noisily: each operation's threads wait for the slower one). The values
        then no longer depend on the thread count either."""
        t = _torch.torch()
        out = []
        with t.inference_mode(), _torch.threads(1):
            ns = (self.name, str(_torch.device()))
            for s in range(0, len(reference), CHUNK):
                f_ref = _torch.per_frame(reference[s:s + CHUNK], ns + ("reference",),
                                         self.frame_features)
                f_gen = _torch.per_frame(generated[s:s + CHUNK], ns + ("generated",),
                                         self.frame_features)
                for fx, fy in zip(f_ref, f_gen):
                    out.append(self.combine(fx, fy).double().cpu().numpy().reshape(-1))
        return np.concatenate(out) if out else np.zeros(0)


def _defaults(fn: Callable) -> dict:
    return {k: p.default for k, p in inspect.signature(fn).parameters.items()
            if p.default is not inspect.Parameter.empty}


def _split(*batches) -> list[tuple]:
    """Per frame, a tuple of its slice (a batch of one) of each batch tensor: views, not copies
    (fresh memory costs page faults; a batch's storage is freed once all its frames are)."""
    return [tuple(b[i:i + 1] for b in batches) for i in range(len(batches[0]))]


class FSIM(_PiqMetric):
    """`piq.fsim(x, y, data_range=1.0, chromatic=True)`: per frame its YIQ I and Q channels,
    the phase congruency and the gradient magnitude of its luma (after piq's average pooling);
    per pair the similarity maps and the PC-weighted mean."""

    name = "fsim"

    def frame_features(self, frames: np.ndarray) -> list[tuple]:
        """`_reference_frame_features` one frame at a time, bit for bit: every operation is per
        frame, and a frame's 16 filter responses stay in the CPU's caches where a batch of four
        does not; the 512² → 256² pooling and the ×255 scaling on OpenCV (a look-up table, an
        area resize: the same float32 values as torch's), and the phase congruency one
        orientation at a time into reused buffers (`_phase_congruency_fast`). Measured: about
        0.5× the CPU time per frame."""
        import piq
        from piq.functional import gradient_map, rgb2yiq, scharr_filter

        t = _torch.torch()
        d = _defaults(piq.fsim)
        out = []
        for i in range(len(frames)):
            x = _fsim_input(frames[i])
            if x is None:  # not uint8 (or an unusual pooling): the reference path
                out += self._reference_frame_features(frames[i:i + 1])
                continue
            x_yiq = rgb2yiq(x)
            x_lum = x_yiq[:, :1]
            pc = _phase_congruency_fast(x_lum, _fsim_filters(x_lum, d), scales=d["scales"],
                                        orientations=d["orientations"], k=d["k"])
            sch = scharr_filter(device=x_lum.device, dtype=x_lum.dtype)
            grad = gradient_map(x_lum, t.stack([sch, sch.transpose(-1, -2)]))
            out += _split(pc, grad, x_yiq[:, 1:2], x_yiq[:, 2:])
        return out

    def _reference_frame_features(self, frames: np.ndarray) -> list[tuple]:
        """The previous path: piq's operations on the batch (tests/test_metric_fast_paths.py
        compares `frame_features` with it)."""
        import piq
        from piq.functional import gradient_map, rgb2yiq, scharr_filter

        t = _torch.torch()
        d = _defaults(piq.fsim)
        x = _torch.to_tensor(frames) / float(1.0) * 255
        x = t.nn.functional.avg_pool2d(x, max(1, round(min(x.shape[-2:]) / 256)))
        x_yiq = rgb2yiq(x)
        x_lum = x_yiq[:, :1]
        pc = _phase_congruency(x_lum, _fsim_filters(x_lum, d), scales=d["scales"],
                               orientations=d["orientations"], k=d["k"])
        sch = scharr_filter(device=x_lum.device, dtype=x_lum.dtype)
        grad = gradient_map(x_lum, t.stack([sch, sch.transpose(-1, -2)]))
        return _split(pc, grad, x_yiq[:, 1:2], x_yiq[:, 2:])

    def combine(self, fx: tuple, fy: tuple):
        from piq.functional import similarity_map

        t = _torch.torch()
        pc_x, grad_map_x, x_i, x_q = fx
        pc_y, grad_map_y, y_i, y_q = fy
        T1, T2, T3, T4, lmbda = 0.85, 160, 200, 200, 0.03  # piq.fsim's constants
        PC = similarity_map(pc_x, pc_y, T1)
        GM = similarity_map(grad_map_x, grad_map_y, T2)
        pc_max = t.where(pc_x > pc_y, pc_x, pc_y)
        score = GM * PC * pc_max
        S_I = similarity_map(x_i, y_i, T3)
        S_Q = similarity_map(x_q, y_q, T4)
        score = score * t.abs(S_I * S_Q) ** lmbda
        return score.sum(dim=[1, 2, 3]) / pc_max.sum(dim=[1, 2, 3])


_FSIM_FILTERS: dict[tuple, Any] = {}


def _fsim_filters(x_lum, d: dict) -> tuple:
    """piq's log-Gabor filter bank for this image size (it depends on nothing else), built by
    piq's ``_construct_filters``, with what piq's ``_phase_congruency`` derives from the filters
    alone (the mean squared smallest-scale filter, and the sums of the spatial filters' squares
    and neighbouring-scale products): once per size, device and dtype."""
    from piq.fsim import _construct_filters

    t = _torch.torch()
    names = ("scales", "orientations", "min_length", "mult", "sigma_f", "delta_theta")
    key = (tuple(x_lum.shape[-2:]), str(x_lum.device), x_lum.dtype) + tuple(d[n] for n in names)
    if key not in _FSIM_FILTERS:
        filters = _construct_filters(x_lum, *(d[n] for n in names))
        scales, orientations = d["scales"], d["orientations"]
        H, W = x_lum.shape[-2:]
        # piq's _phase_congruency, the lines that read the filters only (batch of one)
        filters_ifft = t.fft.ifft2(filters)
        filters_ifft = filters_ifft.real * math.sqrt(H * W)
        em_n = (filters.view(1, orientations, scales, H, W)[:, :, :1, ...] ** 2).sum(
            dim=[-2, -1], keepdims=True)
        filters_ifft = filters_ifft.view(1, orientations, scales, H, W)
        sum_an2 = t.sum(filters_ifft ** 2, dim=-3, keepdim=True)
        sum_ai_aj = t.zeros(1, orientations, 1, H, W, dtype=x_lum.dtype, device=x_lum.device)
        for s in range(scales - 1):
            sum_ai_aj = sum_ai_aj + (filters_ifft[:, :, s: s + 1]
                                     * filters_ifft[:, :, s + 1:]).sum(dim=-3, keepdim=True)
        sum_an2 = t.sum(sum_an2, dim=[-1, -2], keepdim=True)
        sum_ai_aj = t.sum(sum_ai_aj, dim=[-1, -2], keepdim=True)
        _FSIM_FILTERS[key] = (filters, em_n, sum_an2, sum_ai_aj)
    return _FSIM_FILTERS[key]


_SCALE_LUTS: dict[str, np.ndarray] = {}


def _scale_lut(kind: str) -> np.ndarray:
    """float32 value of each uint8 level after `_torch.to_tensor` (÷ 255) and the metric's
    rescaling, computed by the same torch operations (so a look-up gives the same floats):
    ``fsim``: ÷ 1.0 × 255 (piq.fsim, data_range 1); ``vsi``: × 255 ÷ 1.0 (piq.vsi) and
    ``vsi_sdsp``: that, then ÷ 255 × 255 (piq's sdsp)."""
    if kind not in _SCALE_LUTS:
        t = _torch.torch()
        u = t.arange(256, dtype=t.uint8).float() / 255.0
        x = {"fsim": lambda: u / float(1.0) * 255,
             "vsi": lambda: u * 255. / float(1.0),
             "vsi_sdsp": lambda: (u * 255. / float(1.0)) / float(255) * 255}[kind]()
        _SCALE_LUTS[kind] = np.ascontiguousarray(x.numpy(), np.float32)
    return _SCALE_LUTS[kind]


def _fsim_input(frame: np.ndarray):
    """piq.fsim's input of one H×W×3 uint8 frame — ×255 (data_range 1) and average-pooled by
    ``round(min(H, W) / 256)`` — as a 1×3×h×w tensor laid out as torch's path lays it out
    (channels last), the same float32 values: the scaling by a look-up table, 2×2 pooling by
    OpenCV's area resize (the block mean, bit for bit). None where the frame is not uint8 or
    the pooling is not 1 or 2 (the caller takes the reference path)."""
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] < 3:
        return None
    h, w = frame.shape[:2]
    k = max(1, round(min(h, w) / 256))
    if k > 2:
        return None
    x = cv2.LUT(np.ascontiguousarray(frame[..., :3]), _scale_lut("fsim"))
    if k == 2:
        x = cv2.resize(x[:h // 2 * 2, :w // 2 * 2], (w // 2, h // 2),
                       interpolation=cv2.INTER_AREA)
    t = _torch.torch()
    return t.from_numpy(np.ascontiguousarray(x)).to(_torch.device())[None].permute(0, 3, 1, 2)


_FSIM_COMPLEX: dict[int, Any] = {}


def _phase_congruency_fast(x, bank: tuple, scales: int, orientations: int, k: float):
    """`_phase_congruency` (piq's), bit for bit, one orientation at a time: its four filter
    responses, their amplitudes and the energy terms in reused buffers (a 256² frame's 16
    responses are 8 MiB of complex values; one orientation's stay in the CPU's caches), the
    same operations in the same order, and the filter bank as complex values once (piq's
    product converts it on every call). The amplitudes of all 16 responses and the energies
    of the four orientations are kept whole for the final sums and median (the same
    reductions on tensors of the same shapes). Measured: about 0.7× the CPU time."""
    t = _torch.torch()
    filters, em_n, sum_an2, sum_ai_aj = bank
    EPS = t.finfo(x.dtype).eps
    N, _, H, W = x.shape
    O, S = orientations, scales
    fc = _FSIM_COMPLEX.get(id(filters))
    if fc is None or fc[0] is not filters:
        fc = _FSIM_COMPLEX[id(filters)] = (
            filters, filters.to(t.complex64 if x.dtype == t.float32 else t.complex128)
            .reshape(O, S, H, W))
    fc = fc[1]
    imagefft = t.fft.fft2(x)
    new = lambda *shape: t.empty(*shape, dtype=x.dtype, device=x.device)  # noqa: E731
    an = new(N, O, S, H, W)
    energy = new(N, O, 1, H, W)
    even, odd, a, b = (new(N, S, H, W) for _ in range(4))
    sum_e, sum_o, x_energy, tmp = (new(N, 1, H, W) for _ in range(4))
    for o in range(O):
        eo = t.fft.ifft2(imagefft * fc[o])
        even.copy_(eo.real)
        odd.copy_(eo.imag)
        del eo
        t.pow(even, 2, out=a)                   # an = sqrt(even ** 2 + odd ** 2)
        t.pow(odd, 2, out=b)
        t.add(a, b, out=a)
        t.sqrt(a, out=an[:, o])
        t.sum(even, dim=1, keepdim=True, out=sum_e)
        t.sum(odd, dim=1, keepdim=True, out=sum_o)
        t.pow(sum_e, 2, out=x_energy)           # sqrt(sum_e ** 2 + sum_o ** 2) + EPS
        t.pow(sum_o, 2, out=tmp)
        x_energy.add_(tmp).sqrt_().add_(EPS)
        mean_e, mean_o = sum_e.div_(x_energy), sum_o.div_(x_energy)
        t.mul(even, mean_o, out=a)              # |even * mean_o - odd * mean_e|
        t.mul(odd, mean_e, out=b)
        a.sub_(b).abs_()
        even.mul_(mean_e)                       # even * mean_e + odd * mean_o - |…|
        odd.mul_(mean_o)
        even.add_(odd).sub_(a)
        t.sum(even, dim=1, keepdim=True, out=energy[:, o])
    abs_eo = an[:, :, :1].reshape(N, O, 1, 1, H * W)
    return _thresholded_congruency(energy, an, _lower_median(abs_eo ** 2), em_n, sum_an2,
                                   sum_ai_aj, k, EPS)


def _lower_median(x):
    """``torch.median(x, dim=-1, keepdim=True).values`` (the lower of the two middle values:
    the ``(n - 1) // 2``-th smallest), by numpy's introselect where the values are finite and
    on the CPU: the same element, at about a fifteenth of the CPU time (65536 values)."""
    t = _torch.torch()
    n = x.shape[-1]
    if n == 0 or x.device.type != "cpu" or not bool(t.isfinite(x).all()):
        return t.median(x, dim=-1, keepdim=True).values
    k = (n - 1) // 2
    picked = np.partition(x.numpy(), k, axis=-1)[..., k:k + 1]
    return t.from_numpy(np.ascontiguousarray(picked))


def _phase_congruency(x, bank: tuple, scales: int, orientations: int, k: float):
    """piq's ``fsim._phase_congruency(x, filters, scales, orientations, k)`` (its torch ≥ 1.8
    branch), operation for operation, with two changes that leave every value bit for bit the
    same: the filters' own terms come from `_fsim_filters` (piq recomputes them, 16 inverse
    FFTs at 256², on every call), and the even and odd filter responses are contiguous planes
    rather than the interleaved real/imaginary view (piq's strided arithmetic on that view is
    a fifth slower)."""
    t = _torch.torch()
    filters, em_n, sum_an2, sum_ai_aj = bank
    EPS = t.finfo(x.dtype).eps
    N, _, H, W = x.shape
    imagefft = t.fft.fft2(x)
    eo = t.fft.ifft2(imagefft * filters)
    even = eo.real.contiguous().view(N, orientations, scales, H, W)
    odd = eo.imag.contiguous().view(N, orientations, scales, H, W)
    del eo
    an = t.sqrt(even ** 2 + odd ** 2)  # piq: sqrt(sum(even_odd ** 2, dim=-1))
    sum_e = even.sum(dim=2, keepdims=True)
    sum_o = odd.sum(dim=2, keepdims=True)
    x_energy = t.sqrt(sum_e ** 2 + sum_o ** 2) + EPS
    mean_e = sum_e / x_energy
    mean_o = sum_o / x_energy
    energy = (even * mean_e + odd * mean_o - t.abs(even * mean_o - odd * mean_e)).sum(
        dim=2, keepdim=True)
    abs_eo = an[:, :, :1].reshape(N, orientations, 1, 1, H * W)  # piq recomputes it
    return _thresholded_congruency(
        energy, an, t.median(abs_eo ** 2, dim=-1, keepdim=True).values, em_n, sum_an2,
        sum_ai_aj, k, EPS)


def _thresholded_congruency(energy, an, median_e2n, em_n, sum_an2, sum_ai_aj, k: float,
                            EPS: float):
    """piq's phase congruency from the local energy on: the noise threshold estimated from
    the smallest scale's median squared amplitude (``median_e2n``), the energy above it, over
    the summed amplitudes. Shared by the fast path and the reference one, operation for
    operation."""
    t = _torch.torch()
    mean_e2n = - median_e2n / math.log(0.5)
    noise_power = mean_e2n / em_n
    noise_energy2 = 2 * noise_power * sum_an2 + 4 * noise_power * sum_ai_aj
    tau = t.sqrt(noise_energy2 / 2)
    noise_energy = tau * math.sqrt(math.pi / 2)
    moise_energy_sigma = t.sqrt((2 - math.pi / 2) * tau ** 2)
    T = noise_energy + k * moise_energy_sigma
    T = T / 1.7
    energy = t.max(energy - T, t.zeros_like(T))
    energy_all = energy.sum(dim=[1, 2]) + EPS
    an_all = an.sum(dim=[1, 2]) + EPS
    result_pc = energy_all / an_all
    return result_pc.unsqueeze(1)


#: piq's RGB → LMN matrix (`piq.functional.rgb2lmn`)
_RGB_TO_LMN = ((0.06, 0.63, 0.27), (0.30, 0.04, -0.35), (0.34, -0.6, 0.17))
_SDSP_MAPS: dict[tuple, Any] = {}


def _sdsp(x, d: dict):
    """`piq.vsi.sdsp(x, data_range=255, …)` of an N×3×H×W batch already rescaled as sdsp
    rescales it (``x / 255 * 255``), bit for bit: piq's operations, with the log-Gabor filter
    and the centre-bias map (which depend on the 256² working size only) built once."""
    from piq.functional import get_meshgrid, rgb2lab
    from piq.vsi import _log_gabor

    t = _torch.torch()
    F = t.nn.functional
    size = x.size()
    size_to_use = (256, 256)
    x = F.interpolate(input=x, size=size_to_use, mode="bilinear", align_corners=False)
    x_lab = rgb2lab(x, data_range=255)
    key = (str(x_lab.device), x_lab.dtype, d["omega_0"], d["sigma_f"], d["sigma_d"])
    if key not in _SDSP_MAPS:
        xx, yy = get_meshgrid(size_to_use, device=x_lab.device, dtype=x_lab.dtype)
        lg = _log_gabor(xx, yy, d["omega_0"], d["sigma_f"]).view(1, 1, *size_to_use)
        coordinates = t.stack([xx, yy], dim=0)
        coordinates = coordinates * size_to_use[0] + 1
        s_d = t.exp(-t.sum(coordinates ** 2, dim=0) / d["sigma_d"] ** 2).view(
            1, 1, *size_to_use)
        _SDSP_MAPS[key] = (lg, s_d)
    lg, s_d = _SDSP_MAPS[key]
    x_fft = t.fft.fft2(x_lab)
    x_ifft_real = t.fft.ifft2(x_fft * lg).real
    s_f = x_ifft_real.pow(2).sum(dim=1, keepdim=True).sqrt()
    eps = t.finfo(x_lab.dtype).eps
    min_x = x_lab.min(dim=-1, keepdim=True).values.min(dim=-2, keepdim=True).values
    max_x = x_lab.max(dim=-1, keepdim=True).values.max(dim=-2, keepdim=True).values
    normalized = (x_lab - min_x) / (max_x - min_x + eps)
    norm = normalized[:, 1:].pow(2).sum(dim=1, keepdim=True)
    s_c = 1 - t.exp(-norm / d["sigma_c"] ** 2)
    vs_m = s_f * s_d * s_c
    vs_m = F.interpolate(vs_m, size[-2:], mode="bilinear", align_corners=True)
    min_vs_m = vs_m.min(dim=-1, keepdim=True).values.min(dim=-2, keepdim=True).values
    max_vs_m = vs_m.max(dim=-1, keepdim=True).values.max(dim=-2, keepdim=True).values
    return (vs_m - min_vs_m) / (max_vs_m - min_vs_m + eps)


class VSI(_PiqMetric):
    """`piq.vsi(x, y, data_range=1.0)`: per frame its SDSP saliency map, its LMN channels (both
    padded and average-pooled as piq does) and the gradient magnitude of L; per pair the
    similarity maps and the saliency-weighted mean."""

    name = "vsi"

    def frame_features(self, frames: np.ndarray) -> list[tuple]:
        """`_reference_frame_features` one frame at a time: the ×255 scalings by look-up
        tables (the same floats), piq's SDSP with its constant maps (log-Gabor filter, centre
        bias) built once per size (`_sdsp`), and the LMN channels padded and pooled by OpenCV
        (its area resize is torch's 2×2 mean on this layout): every value bit for bit.
        (Pooling the frame before the LMN conversion, both linear, would save another 1.5 ms
        a frame but moves LMN by an ulp, and VSI's |s_c|^0.02 turns that into up to 1.4e-5
        on noise frames, where s_c crosses 0.) Measured: about 0.75× the CPU time per
        frame."""
        import piq
        from piq.functional import gradient_map, scharr_filter

        t = _torch.torch()
        d = _defaults(piq.vsi)
        out = []
        for i in range(len(frames)):
            frame = np.asarray(frames[i])
            h, w = frame.shape[:2]
            kernel_size = max(1, round(min(h, w) / 256))
            if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] < 3 \
                    or kernel_size > 2:
                out += self._reference_frame_features(frames[i:i + 1])
                continue
            rgb = np.ascontiguousarray(frame[..., :3])
            x1 = t.from_numpy(cv2.LUT(rgb, _scale_lut("vsi_sdsp"))).to(_torch.device())
            vs_x = _sdsp(x1[None].permute(0, 3, 1, 2), d)
            x = t.from_numpy(cv2.LUT(rgb, _scale_lut("vsi"))).to(_torch.device())[None]
            weights = t.tensor(_RGB_TO_LMN, dtype=x.dtype, device=x.device).t()
            x_lmn = t.matmul(x, weights)  # piq's rgb2lmn (on the same N×H×W×3 layout)
            if kernel_size == 2:  # replicate pad of 1 at the top and left, then 2×2 means
                vs_x = t.nn.functional.avg_pool2d(
                    t.nn.functional.pad(vs_x, pad=[1, 0, 1, 0], mode="replicate"), 2)
                lmn = cv2.copyMakeBorder(x_lmn[0].cpu().numpy(), 1, 0, 1, 0,
                                         cv2.BORDER_REPLICATE)
                lmn = cv2.resize(lmn[:(h + 1) // 2 * 2, :(w + 1) // 2 * 2],
                                 ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA)
                x_lmn = t.from_numpy(np.ascontiguousarray(lmn)).to(_torch.device())[None]
            x_lmn = x_lmn.permute(0, 3, 1, 2)
            sch = scharr_filter(device=x_lmn.device, dtype=x_lmn.dtype)
            gm_x = gradient_map(x_lmn[:, :1], t.stack([sch, sch.transpose(1, 2)]))
            out += _split(vs_x, gm_x, x_lmn[:, 1:2], x_lmn[:, 2:])
        return out

    def _reference_frame_features(self, frames: np.ndarray) -> list[tuple]:
        """The previous path: piq's operations on the batch (tests/test_metric_fast_paths.py
        compares `frame_features` with it)."""
        import piq
        from piq.functional import gradient_map, rgb2lmn, scharr_filter
        from piq.vsi import sdsp

        t = _torch.torch()
        F = t.nn.functional
        d = _defaults(piq.vsi)
        x = _torch.to_tensor(frames) * 255. / float(1.0)
        vs_x = sdsp(x, data_range=255, omega_0=d["omega_0"], sigma_f=d["sigma_f"],
                    sigma_d=d["sigma_d"], sigma_c=d["sigma_c"])
        x_lmn = rgb2lmn(x)
        kernel_size = max(1, round(min(vs_x.size()[-2:]) / 256))
        padding = kernel_size // 2
        if padding:
            bottom = (kernel_size - 1) // 2
            pad_to_use = [padding, bottom, padding, bottom]
            vs_x = F.pad(vs_x, pad=pad_to_use, mode="replicate")
            x_lmn = F.pad(x_lmn, pad=pad_to_use, mode="replicate")
        vs_x = F.avg_pool2d(vs_x, kernel_size=kernel_size)
        x_lmn = F.avg_pool2d(x_lmn, kernel_size=kernel_size)
        sch = scharr_filter(device=x_lmn.device, dtype=x_lmn.dtype)
        gm_x = gradient_map(x_lmn[:, :1], t.stack([sch, sch.transpose(1, 2)]))
        return _split(vs_x, gm_x, x_lmn[:, 1:2], x_lmn[:, 2:])

    def combine(self, fx: tuple, fy: tuple):
        import piq
        from piq.functional import similarity_map

        t = _torch.torch()
        d = _defaults(piq.vsi)
        c1, c2, c3, alpha, beta = d["c1"], d["c2"], d["c3"], d["alpha"], d["beta"]
        vs_x, gm_x, x_m, x_n = fx
        vs_y, gm_y, y_m, y_n = fy
        s_vs = similarity_map(vs_x, vs_y, c1)
        s_gm = similarity_map(gm_x, gm_y, c2)
        s_m = similarity_map(x_m, y_m, c3)
        s_n = similarity_map(x_n, y_n, c3)
        s_c = s_m * s_n
        s_c_complex = [s_c.abs(), t.atan2(t.zeros_like(s_c), s_c)]
        s_c_complex_pow = [s_c_complex[0] ** beta, s_c_complex[1] * beta]
        s_c_real_pow = s_c_complex_pow[0] * t.cos(s_c_complex_pow[1])
        s = s_vs * s_gm.pow(alpha) * s_c_real_pow
        vs_max = t.max(vs_x, vs_y)
        eps = t.finfo(vs_max.dtype).eps
        output = s * vs_max
        return ((output.sum(dim=(-1, -2)) + eps) / (vs_max.sum(dim=(-1, -2)) + eps)).squeeze(-1)


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
    return _split(*[normalize_tensor(o) for o in outs])


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
    register(MSSSIM())
    register(FSIM())
    register(VSI())
    register(LPIPS())
    register(STLPIPS())
    register(DISTS())
