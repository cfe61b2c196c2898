"""Pixel metrics on aligned frame pairs: PSNR and SSIM (weight-free, numpy/OpenCV).

SSIM follows Wang et al. 2004 (11-tap Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03, L = 255,
borders of the filter radius cropped), computed on the luma Y (BT.601) and on R, G and B, and
averaged over those four channels (MISSION §6: "mean over Y and R,G,B").

Cost (one 512² pair, one core, this project's 2-core machines). SSIM is five separable 11-tap
blurs per channel (OpenCV float32, about 0.7 ms each at 512²), twenty per pair: two of them
(the mean and the mean square) depend on one frame only. `SSIM.pair_values` computes those once
per distinct frame (`visphy_plugins.metrics._torch.per_frame`: kept across the scorer's calls
for the three pairings of a scene) and only the cross term per pair:

==================================  ============  ==========================================
SSIM                                s / 2D scene  blurs (32 distinct pairs, 34 frames)
==================================  ============  ==========================================
per pair (before)                   0.45–0.52     32 × 20 = 640
per distinct frame + cross term     see bench     34 × 8 + 32 × 4 = 400
==================================  ============  ==========================================

The values are bit for bit those of `ssim_frame` (the same float32 operations in the same
order). PSNR is a mean of squared differences: nothing to share.
"""

from __future__ import annotations

import cv2
import numpy as np

from visphy_core.hookspecs import hookimpl
from visphy_core.metrics import HIGHER, PAIRS, Metric
from visphy_plugins.metrics import _torch

PSNR_CAP_DB = 100.0  # identical frames: report the cap instead of infinity
_SIGMA, _RADIUS = 1.5, 5
_C1, _C2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2


def psnr_frame(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    if mse <= 255.0**2 * 10 ** (-PSNR_CAP_DB / 10):
        return PSNR_CAP_DB
    return 10.0 * np.log10(255.0**2 / mse)


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


def _frame_moments(frames: np.ndarray) -> list[np.ndarray]:
    """Per frame: the local mean and variance of each of its four channels, one 4×2×H×W
    float32 array (one allocation: fresh memory is paid in page faults, per page)."""
    out = []
    for f in frames:
        m = np.empty((4, 2, *f.shape[:2]), np.float32)
        for c, x in enumerate(_channels(f)):
            cv2.sepFilter2D(x, -1, _KERNEL, _KERNEL, dst=m[c, 0], borderType=cv2.BORDER_REFLECT)
            cv2.sepFilter2D(x * x, -1, _KERNEL, _KERNEL, dst=m[c, 1],
                            borderType=cv2.BORDER_REFLECT)
            m[c, 1] -= m[c, 0] * m[c, 0]
        out.append(m)
    return out


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
        """`ssim_frame` of each pair, each frame's moments computed once (`_torch.per_frame`)."""
        m_ref = _torch.per_frame(reference, ("ssim", "reference"), _frame_moments)
        m_gen = _torch.per_frame(generated, ("ssim", "generated"), _frame_moments)
        work = _Work(np.shape(reference)[1:3]) if len(reference) else None
        out = []
        for a, b, ma, mb in zip(reference, generated, m_ref, m_gen):
            vals = [_ssim_map_mean(x, y, *sa, *sb, work=work)
                    for x, y, sa, sb in zip(_channels(a), _channels(b), ma, mb)]
            out.append(float(np.mean(vals)))
        return np.array(out)


@hookimpl
def visphy_register_metrics(register):
    register(PSNR())
    register(SSIM())
