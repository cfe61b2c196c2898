"""MS-SSIM on aligned frame pairs (family ``perceptual``, kind ``pairs``): weight-free, equal to
piq 0.8's function on [0, 1] RGB tensors with ``data_range=1``.

* ``ms_ssim`` ↑ [0, 1]: `piq.multi_scale_ssim` (5 scales, 11-tap Gaussian σ 1.5, Wang 2003
  weights), re-implemented with separable OpenCV float32 filters (`ms_ssim_pair`: piq's
  valid-mode windows, its replicate padding and 2×2 average pooling between scales, the cs
  means at scales 1–4 and the SSIM mean at scale 5, relu, the weights' product, the mean over
  R, G, B last). It equals piq's float32 value within 1e-5 (a few 1e-6 on rendered frames:
  piq's own float32 rounding; the value here is closer to piq's float64 result). Frames need
  at least 161 px a side (`MS_SSIM_MIN_SIZE`); smaller frames give NaN (recorded as None).
  Needs neither torch nor piq.

Cost. CPU seconds per pair at 512² (this project's 2-core machines, shared; the lowest of
repeated runs of 8 pairs): piq's full 11×11 convolutions in torch 0.09–0.12; OpenCV's separable
filters here, 5 scales from 512², 0.016.

MS-SSIM's per-frame share (two of five blurs per scale) is not cached: its 12 MiB of maps per
512² frame cost about as much in fresh memory as they would save on the frames a 2D scene
reuses. At most `MS_SSIM_MAX_PAIRS` (8) pairs per pairing, evenly spaced
(`visphy_plugins.metrics._pairs` explains the default; ``metrics.max_pairs.ms_ssim``
overrides).
"""

from __future__ import annotations

import cv2
import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import HIGHER, PAIRS, Metric

#: ``max_pairs`` default (per pairing; `visphy_plugins.metrics._pairs` for the reasoning).
MS_SSIM_MAX_PAIRS = 8
MS_SSIM_MIN_SIZE = 161  # (11 - 1) * 2 ** 4 + 1

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
    max_pairs = MS_SSIM_MAX_PAIRS

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        if min(np.shape(reference)[1:3]) < MS_SSIM_MIN_SIZE:
            return np.full(len(reference), np.nan)
        scales = _ms_ssim_scales(*np.shape(reference)[1:3]) if len(reference) else None
        return np.array([ms_ssim_pair(a, b, scales) for a, b in zip(reference, generated)])



@hookimpl
def visphy_register_metrics(register):
    register(MSSSIM())
