"""Pixel metrics on aligned frame pairs: PSNR and SSIM (weight-free, numpy/scipy).

SSIM follows Wang et al. 2004 (11-tap Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03, L = 255,
borders of the filter radius cropped), computed on the luma Y (BT.601) and on R, G and B, and
averaged over those four channels (MISSION §6: "mean over Y and R,G,B").
"""

from __future__ import annotations

import cv2
import numpy as np

from visphy_core.hookspecs import hookimpl
from visphy_core.metrics import HIGHER, PAIRS, Metric

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


def ssim_channel(x: np.ndarray, y: np.ndarray) -> float:
    x, y = x.astype(np.float32, copy=False), y.astype(np.float32, copy=False)
    mx, my = _blur(x), _blur(y)
    sxx = _blur(x * x) - mx * mx
    syy = _blur(y * y) - my * my
    sxy = _blur(x * y) - mx * my
    smap = ((2 * mx * my + _C1) * (2 * sxy + _C2)) / ((mx * mx + my * my + _C1) * (sxx + syy + _C2))
    r = _RADIUS
    return float(smap[r:-r, r:-r].mean(dtype=np.float64))


def _channels(frame: np.ndarray) -> list[np.ndarray]:
    f = frame.astype(np.float32)
    luma = 0.299 * f[..., 0] + 0.587 * f[..., 1] + 0.114 * f[..., 2]
    return [luma, f[..., 0], f[..., 1], f[..., 2]]


def ssim_frame(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean([ssim_channel(x, y) for x, y in zip(_channels(a), _channels(b))]))


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
        return np.array([ssim_frame(a, b) for a, b in zip(reference, generated)])


@hookimpl
def visphy_register_metrics(register):
    register(PSNR())
    register(SSIM())
