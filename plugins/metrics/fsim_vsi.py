"""FSIM and VSI on aligned frame pairs (family ``perceptual``, kind ``pairs``): weight-free,
equal to piq 0.8's functions on [0, 1] RGB tensors with ``data_range=1``.

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

Per-frame work. Each frame's maps are computed once per distinct frame and kept in the
per-frame cache (`visphy_plugins.metrics._torch.per_frame`; `visphy_plugins.metrics._pairs`
says why frames repeat); per pair only the comparison runs, in chunks of `CHUNK` pairs, on one
torch thread (`_PiqMetric.pair_values`). The values equal the per-pair computation to 1e-6
(tested on batches with and without repeated frames).

Cost and ``max_pairs``. CPU seconds at 512², one torch thread (torch 2.14, this project's 2-core
machines, shared; the lowest of repeated runs of 8 pairs): before, per pair as piq computed it;
now, per distinct frame (once per scene) and per pair:

============  ===========  ====================  ==============================================
metric        before       now: frame + pair     what runs
============  ===========  ====================  ==============================================
``vsi``       0.048        0.023 + 0.005         piq, saliency at 256², similarity at 256²
``fsim``      0.074        0.027 + 0.004         piq, phase congruency at 256² (pooled by 2)
============  ===========  ====================  ==============================================

Both run on at most `PIQ_MAX_PAIRS` (8) pairs per pairing, evenly spaced
(`visphy_plugins.metrics._pairs` explains the default; ``metrics.max_pairs.<name>`` overrides).

Fast paths, each next to the path it replaced (kept as the reference and compared
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
"""
# size: one piq port: FSIM and VSI share _PiqMetric, the look-up tables and their reference paths

from __future__ import annotations

import inspect
import math
from typing import Any, Callable

import cv2
import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import HIGHER, PAIRS, Metric
from visphy_plugins.metrics import _torch
from visphy_plugins.metrics._pairs import CHUNK, split_frames

#: ``max_pairs`` default of FSIM and VSI (per pairing; `visphy_plugins.metrics._pairs`).
PIQ_MAX_PAIRS = 8


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
            out += split_frames(pc, grad, x_yiq[:, 1:2], x_yiq[:, 2:])
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
        return split_frames(pc, grad, x_yiq[:, 1:2], x_yiq[:, 2:])

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
    O, S = orientations, scales  # noqa: E741 - piq's names
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
            out += split_frames(vs_x, gm_x, x_lmn[:, 1:2], x_lmn[:, 2:])
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
        return split_frames(vs_x, gm_x, x_lmn[:, 1:2], x_lmn[:, 2:])

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


@hookimpl
def visphy_register_metrics(register):
    register(FSIM())
    register(VSI())
