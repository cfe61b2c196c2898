"""Pixel metrics on aligned frame pairs: PSNR and SSIM (weight-free, numpy/OpenCV).

SSIM follows Wang et al. 2004 (11-tap Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03, L = 255,
borders of the filter radius cropped), computed on the luma Y (BT.601) and on R, G and B, and
averaged over those four channels (the paper's "mean over Y and R,G,B").

Cost. SSIM is five separable 11-tap blurs per channel (OpenCV float32), twenty per pair, and
eight of them (each channel's mean and mean square) depend on one frame only. `SSIM` computes
those once per distinct frame and keeps them in the per-frame cache
(`visphy_plugins.metrics._torch.per_frame`) for the scene's other pairings, and only the cross
term per pair, in reused work arrays. CPU seconds at 512², one thread (the lowest of repeated
runs of 8 pairs, on this project's shared 2-core machines):

=================================  =========  ==============================================
SSIM                               s          what runs
=================================  =========  ==============================================
before, per pair                   0.020      20 blurs and the map, fresh arrays throughout
now, per distinct frame            0.007      8 blurs (4 channels' mean and variance)
now, per pair                      0.006      4 blurs (the cross term) and the map in place
=================================  =========  ==============================================

A 2D scene of the benchmark (17 frames, aligned offset 2) has 32 distinct pairs over 34 frames:
about 0.64 s of one core before, 0.43 s now. The moments take 8 MiB per 512² frame: a batch is
kept only when its frames fit in the cache (a 2D pairing's 17 pairs: 270 MiB); a larger one (a
3D scene's 75 pairs, whose frames no later pairing asks for again) is computed pair by pair
into reused arrays. The values are bit for bit those of `ssim_frame` either way (the same
float32 operations in the same order). PSNR is `visphy_core.api.psnr.psnr`, the one per-frame
PSNR the ``paper`` protocol and the report's per-frame curve use too: a mean of squared
differences, with nothing to share between pairs.

Fast path: each frame's Y, R, G, B planes and its moments are computed into reused
work arrays (`_Planes`: a fresh megabyte array per operation cost as much in page faults as
the arithmetic; ``0.299 * r + …`` alone allocated five), bit for bit the previous per-frame
moments (`_reference_moments_into`, compared by tests/test_metric_fast_paths.py). What is left
is mostly the 20 blurs a pair needs where nothing repeats (a 3D scene): about 0.2 ms each at
512², in cache; a strip-by-strip version that keeps a pair's maps in the CPU's caches was
measured at only 0.92× and not kept.
"""

from __future__ import annotations

import cv2
import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import HIGHER, PAIRS, Metric
from visphy_core.api.psnr import PSNR_CAP_DB
from visphy_core.api.psnr import psnr as psnr_frame
from visphy_plugins.metrics import _torch

PAIR_CHUNK = 8  # SSIM pairs whose frames' moments are held at once
_SIGMA, _RADIUS = 1.5, 5
_C1, _C2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2


_TAPS = np.exp(-np.arange(-_RADIUS, _RADIUS + 1) ** 2 / (2 * _SIGMA**2))
_KERNEL = (_TAPS / _TAPS.sum()).astype(np.float32)


def _blur(x: np.ndarray) -> np.ndarray:
    # separable 11-tap Gaussian (OpenCV, float32: ~9× scipy's float64 filter; SSIM within 1e-8
    # of the float64 result). The border mode never matters: every value kept is at least the
    # filter radius from the border (the crop below).
    return cv2.sepFilter2D(x, -1, _KERNEL, _KERNEL, borderType=cv2.BORDER_REFLECT)


def _moments(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One channel's local mean and variance (float32 maps): what SSIM needs of one image."""
    mx = _blur(x)
    sxx = _blur(x * x)
    sxx -= mx * mx
    return mx, sxx


class _Work:
    """Work arrays for `_ssim_map_mean` at one frame size (fresh megabyte arrays for every
    operation cost as much as the arithmetic)."""

    def __init__(self, shape: tuple[int, int]):
        self.shape = shape
        self.a, self.b, self.c = (np.empty(shape, np.float32) for _ in range(3))


def _ssim_map_mean(x: np.ndarray, y: np.ndarray, mx: np.ndarray, sxx: np.ndarray,
                   my: np.ndarray, syy: np.ndarray, work: _Work | None = None) -> float:
    """The mean SSIM map of one channel, borders of the filter radius cropped:
    ((2 μx μy + C1)(2 σxy + C2)) / ((μx² + μy² + C1)(σx² + σy² + C2)), float32, the mean in
    float64."""
    if work is None or work.shape != x.shape:
        work = _Work(x.shape)
    num, den, t = work.a, work.b, work.c
    np.multiply(x, y, out=t)
    sxy = cv2.sepFilter2D(t, -1, _KERNEL, _KERNEL, dst=work.c, borderType=cv2.BORDER_REFLECT)
    np.multiply(mx, my, out=num)
    sxy -= num            # σxy = blur(xy) − μx μy
    num *= 2
    num += _C1            # 2 μx μy + C1
    sxy *= 2
    sxy += _C2            # 2 σxy + C2
    num *= sxy
    np.multiply(mx, mx, out=den)
    np.multiply(my, my, out=t)
    den += t
    den += _C1            # μx² + μy² + C1
    np.add(sxx, syy, out=t)
    t += _C2              # σx² + σy² + C2
    den *= t
    num /= den
    r = _RADIUS
    return float(num[r:-r, r:-r].mean(dtype=np.float64))


def ssim_channel(x: np.ndarray, y: np.ndarray) -> float:
    x = np.ascontiguousarray(x, dtype=np.float32)
    y = np.ascontiguousarray(y, dtype=np.float32)
    return _ssim_map_mean(x, y, *_moments(x), *_moments(y))


def _channels(frame: np.ndarray) -> list[np.ndarray]:
    """Y (BT.601), R, G, B of an H×W×3 uint8 frame as contiguous float32 planes."""
    r, g, b = (c.astype(np.float32) for c in cv2.split(np.ascontiguousarray(frame[..., :3])))
    luma = 0.299 * r + 0.587 * g + 0.114 * b
    return [luma, r, g, b]


def ssim_frame(a: np.ndarray, b: np.ndarray) -> float:
    """SSIM of one pair of H×W×3 uint8 frames (mean over Y, R, G, B)."""
    return float(np.mean([ssim_channel(x, y) for x, y in zip(_channels(a), _channels(b))]))


_LUMA = (np.float32(0.299), np.float32(0.587), np.float32(0.114))


class _Planes:
    """One frame's Y, R, G, B float32 planes (4×H×W) and a scratch plane, reused from frame
    to frame: a fresh megabyte array costs more in page faults than the arithmetic on it."""

    def __init__(self, shape: tuple[int, int]):
        self.shape = shape
        self.p = np.empty((4, *shape), np.float32)
        self.t = np.empty(shape, np.float32)

    def load(self, frame: np.ndarray) -> np.ndarray:
        """`_channels` of ``frame`` into the planes, bit for bit (the same float32 operations
        in the same order: (0.299 R + 0.587 G) + 0.114 B)."""
        p, t = self.p, self.t
        for c, plane in enumerate(cv2.split(np.ascontiguousarray(frame[..., :3]))):
            p[c + 1] = plane
        np.multiply(p[1], _LUMA[0], out=p[0])
        np.multiply(p[2], _LUMA[1], out=t)
        p[0] += t
        np.multiply(p[3], _LUMA[2], out=t)
        p[0] += t
        return p

    def moments(self, m: np.ndarray) -> np.ndarray:
        """The loaded frame's local mean and variance of each channel into ``m`` (4×2×H×W
        float32), as `_moments` computes them."""
        p, t = self.p, self.t
        for c in range(4):
            cv2.sepFilter2D(p[c], -1, _KERNEL, _KERNEL, dst=m[c, 0],
                            borderType=cv2.BORDER_REFLECT)
            np.multiply(p[c], p[c], out=t)
            cv2.sepFilter2D(t, -1, _KERNEL, _KERNEL, dst=m[c, 1], borderType=cv2.BORDER_REFLECT)
            np.multiply(m[c, 0], m[c, 0], out=t)
            m[c, 1] -= t
        return m


def _reference_moments_into(frame: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The previous per-frame moments (fresh arrays for every operation): `_Planes.moments`
    must equal it bit for bit (tests/test_metric_fast_paths.py)."""
    for c, x in enumerate(_channels(frame)):
        cv2.sepFilter2D(x, -1, _KERNEL, _KERNEL, dst=m[c, 0], borderType=cv2.BORDER_REFLECT)
        cv2.sepFilter2D(x * x, -1, _KERNEL, _KERNEL, dst=m[c, 1], borderType=cv2.BORDER_REFLECT)
        m[c, 1] -= m[c, 0] * m[c, 0]
    return m


def _moments_into(frame: np.ndarray, m: np.ndarray, planes: _Planes | None = None
                  ) -> np.ndarray:
    """``frame``'s local mean and variance of each of its four channels into ``m`` (4×2×H×W
    float32: one array, one allocation; fresh memory is paid in page faults, per page)."""
    planes = planes if planes is not None and planes.shape == frame.shape[:2] \
        else _Planes(frame.shape[:2])
    planes.load(frame)
    return planes.moments(m)


def _frame_moments(frames: np.ndarray) -> list[np.ndarray]:
    planes = _Planes(frames.shape[1:3]) if len(frames) else None
    return [_moments_into(f, np.empty((4, 2, *f.shape[:2]), np.float32), planes)
            for f in frames]


class PSNR(Metric):
    name = "psnr"
    direction = HIGHER
    score_range = (0.0, PSNR_CAP_DB)
    family = "pixel"
    kind = PAIRS

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        return np.array([psnr_frame(a, b) for a, b in zip(reference, generated)])


class SSIM(Metric):
    name = "ssim"
    direction = HIGHER
    score_range = (-1.0, 1.0)
    family = "pixel"
    kind = PAIRS

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        """`ssim_frame` of each pair. When the batch's frames fit in the per-frame cache, each
        frame's moments are computed once and kept for the scene's next pairings
        (`_torch.per_frame`); a batch too large to keep (a 3D scene's 75 pairs: 1.2 GB of
        moments, and nothing comes back for them) computes them pair by pair into reused
        arrays instead. Same values either way."""
        n = len(reference)
        if n == 0:
            return np.zeros(0)
        h, w = np.shape(reference)[1:3]
        work = _Work((h, w))
        pa, pb = _Planes((h, w)), _Planes((h, w))
        keep = 2 * n * 4 * 2 * h * w * 4 <= _torch.FRAME_CACHE_BYTES
        if not keep:
            ma, mb = (np.empty((4, 2, h, w), np.float32) for _ in range(2))
        out = []
        for s in range(0, n, PAIR_CHUNK):
            ref, gen = reference[s:s + PAIR_CHUNK], generated[s:s + PAIR_CHUNK]
            if keep:
                m_ref = _torch.per_frame(ref, ("ssim", "reference"), _frame_moments)
                m_gen = _torch.per_frame(gen, ("ssim", "generated"), _frame_moments)
            for i, (a, b) in enumerate(zip(ref, gen)):
                xa, xb = pa.load(a), pb.load(b)
                if keep:
                    sa, sb = m_ref[i], m_gen[i]
                else:
                    sa, sb = pa.moments(ma), pb.moments(mb)
                vals = [_ssim_map_mean(xa[c], xb[c], *sa[c], *sb[c], work=work)
                        for c in range(4)]
                out.append(float(np.mean(vals)))
        return np.array(out)


@hookimpl
def visphy_register_metrics(register):
    register(PSNR())
    register(SSIM())
