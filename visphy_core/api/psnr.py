"""The one per-frame PSNR: the ``psnr`` metric, the ``paper`` protocol and the report's
per-frame curve all call `psnr`, so the curve shows the values behind the ``psnr`` column.

PSNR is 10·log10(255² / MSE) over every 8-bit channel. The rules differ only in what counts as
a perfect match, reported as `PSNR_CAP_DB` instead of infinity:

* visphy (`VISPHY_PERFECT_MSE`, the default): every MSE at which PSNR would reach the cap, so
  no frame scores above 100 dB (the metric's declared range);
* upstream's ``compute_psnr`` (`PAPER_PERFECT_MSE`, used by the ``paper`` protocol): an MSE
  ≤ 1e-10, so nearly identical frames score above 100 dB as they do in the paper's tables.
"""

from __future__ import annotations

import numpy as np

#: What a perfect match scores (dB), instead of infinity.
PSNR_CAP_DB = 100.0
#: visphy's rule: an MSE at or below this gives `PSNR_CAP_DB` (PSNR would reach the cap).
VISPHY_PERFECT_MSE = 255.0**2 * 10 ** (-PSNR_CAP_DB / 10)
#: Upstream's rule (``compute_psnr``): only an MSE ≤ 1e-10 gives `PSNR_CAP_DB`.
PAPER_PERFECT_MSE = 1e-10


def _mse(a: np.ndarray, b: np.ndarray) -> float:
    """The mean squared difference. Two 8-bit frames are summed as integers (exact, in int64):
    the value numpy's float64 mean gives, whose partial sums are exact integers too, at a
    quarter of the time."""
    if a.dtype == np.uint8 and b.dtype == np.uint8 and a.shape == b.shape:
        d = np.subtract(a, b, dtype=np.int16).ravel()
        return float(np.einsum("i,i->", d, d, dtype=np.int64)) / d.size
    d = a.astype(np.float64) - b.astype(np.float64)
    return float(np.sum(d * d)) / d.size


def psnr(a: np.ndarray, b: np.ndarray, perfect_mse: float = VISPHY_PERFECT_MSE) -> float:
    """PSNR (dB) of two frames of one shape, 8-bit values; an MSE ≤ ``perfect_mse`` is a
    perfect match, `PSNR_CAP_DB` (see the module docstring for the two rules). Frames without
    a pixel score 0.0, as upstream's."""
    if a.size == 0:
        return 0.0
    mse = _mse(a, b)
    if mse <= perfect_mse:
        return PSNR_CAP_DB
    return float(10.0 * np.log10(255.0**2 / mse))
