"""Temporal alignment of a generated clip to its reference: once, vectorised, for every metric.

Two scoring protocols use it (docs/metrics.md):

* ``paper`` (``rules="upstream"``, `PAPER`): upstream's ``utils/evaluate_video_metrics.py::
  evaluate_pair`` pairing, rule by rule, implemented in `visphy_core.scoring.paper_protocol` (every
  3rd frame by index; coarse candidates from centred, L2-normalised 64² grayscale vectors, the
  ``top_k`` (5) best plus 0 and ±1, ±2 always; each refined on ONE stack of ``window`` (3)
  frames at the start of the overlap on raw intensities, cost MSE + 0.5·MAE + 0.1·(1 − cosine)
  + ``offset_penalty`` (0.05)·|offset|; the clips trimmed to that offset; then DTW (``dtw``, on
  by default) over 48² grayscale features with step penalty 0.005 on the trimmed clips).
* ``visphy``: every frame paired by time, unaligned (``unaligned``), plus an offset search on
  every frame (``sample_every=1``, ``rules="visphy"``) reported as the *aligned* variant with
  its offset and Align-Err beside it, so a warp cannot hide a timing error. Its search: a coarse
  search over offsets −``max_offset``…+``max_offset`` sampled frames compares ``downsample``²
  (64²) grayscale vectors (area-averaged, each standardised to zero mean and unit variance: see
  `standardised`) by MSE over the overlap; the ``top_k`` (5) cheapest offsets are refined on at
  most ``max_samples`` (16) evenly spread sample positions, each compared as a stack of
  ``window`` (3) neighbouring frames, with the same cost and penalty. Optionally (``dtw``) a
  monotone path by dynamic time warping over 48² standardised grayscale features with a step
  penalty (0.005) replaces the single offset.

An `Alignment` is a list of index pairs (reference frame, generated frame) in time order, the
chosen offset in frames of the input clips (generated frame = reference frame + offset), and
``align_err``: the refinement cost at that offset without the penalty (0 on identical clips).
"""

from __future__ import annotations

import cv2
import numpy as np

from visphy_core.api.metrics import Alignment, unaligned
from visphy_core.scoring import paper_protocol
from visphy_core.scoring.pairing import EVERY_FRAME, PAPER, AlignParams

__all__ = ["Alignment", "AlignParams", "EVERY_FRAME", "PAPER", "align", "gray_features",
           "standardised", "unaligned"]


def gray_features(frames: np.ndarray, size: int) -> np.ndarray:
    """N×H×W×3 uint8 → N×(size·size) float32 grayscale in [0, 1], area-averaged."""
    frames = np.asarray(frames)
    n, h, w = frames.shape[:3]
    luma = np.array([0.299, 0.587, 0.114], dtype=np.float32)
    if h % size == 0 and w % size == 0:  # whole blocks: block means (OpenCV's area
        # resampling is the exact block mean for integer factors), then luma (both linear)
        means = np.stack([cv2.resize(f[..., :3].astype(np.float32), (size, size),
                                     interpolation=cv2.INTER_AREA) for f in frames])
        return ((means @ luma) / 255.0).reshape(n, size * size).astype(np.float32)
    gray = (frames[..., :3].astype(np.float32)
            @ np.array([0.299, 0.587, 0.114], dtype=np.float32)) / 255.0
    ys = (np.arange(size + 1) * h) // size
    xs = (np.arange(size + 1) * w) // size
    if h >= size and w >= size:  # block means via cumulative sums (exact area averaging)
        c = np.zeros((n, h + 1, w + 1), dtype=np.float64)
        c[:, 1:, 1:] = gray.cumsum(1).cumsum(2)
        area = np.outer(np.diff(ys), np.diff(xs))
        out = (c[:, ys[1:]][:, :, xs[1:]] - c[:, ys[:-1]][:, :, xs[1:]]
               - c[:, ys[1:]][:, :, xs[:-1]] + c[:, ys[:-1]][:, :, xs[:-1]]) / area
    else:  # smaller than the grid: nearest neighbour
        yi = np.minimum((np.arange(size) * h) // size, h - 1)
        xi = np.minimum((np.arange(size) * w) // size, w - 1)
        out = gray[:, yi][:, :, xi]
    return out.reshape(n, size * size).astype(np.float32)


def standardised(feats: np.ndarray) -> np.ndarray:
    """Each frame's vector at zero mean and unit variance (a flat frame: all zeros), so the
    alignment cost does not depend on how much of the frame the moving objects cover and the
    offset penalty weighs the same against a small ball as against a large block."""
    f = feats.astype(np.float64)
    f = f - f.mean(axis=1, keepdims=True)
    sd = f.std(axis=1, keepdims=True)
    return np.where(sd > 1e-9, f / np.maximum(sd, 1e-9), 0.0).astype(np.float32)


def _overlap(n_ref: int, n_gen: int, off: int) -> tuple[int, int]:
    """Sampled reference positions i with 0 ≤ i + off < n_gen: [lo, hi)."""
    return max(0, -off), min(n_ref, n_gen - off)


def _stack(feats: np.ndarray, idx: np.ndarray, window: int, lo: int, hi: int,
           shift: int = 0) -> np.ndarray:
    """Each position's ``window`` neighbours side by side, kept inside the overlap [lo, hi)
    (so both clips' stacks hold corresponding frames), read at position + ``shift``."""
    half = window // 2
    cols = [np.clip(idx + d, lo, hi - 1) + shift for d in range(-half, window - half)]
    return np.concatenate([feats[c] for c in cols], axis=1)


def _refine_cost(fr: np.ndarray, fg: np.ndarray, off: int, p: AlignParams) -> float:
    lo, hi = _overlap(len(fr), len(fg), off)
    count = hi - lo
    take = min(count, p.max_samples)
    pos = lo + np.unique(np.round(np.linspace(0, count - 1, take)).astype(int))
    a = _stack(fr, pos, p.window, lo, hi).astype(np.float64)
    b = _stack(fg, pos, p.window, lo, hi, shift=off).astype(np.float64)
    d = a - b
    mse = (d * d).mean(axis=1)
    mae = np.abs(d).mean(axis=1)
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    both_zero = (na == 0) & (nb == 0)
    cos = np.where(both_zero, 1.0, (a * b).sum(axis=1) / np.maximum(na * nb, 1e-12))
    return float(np.mean(mse + 0.5 * mae + 0.1 * (1.0 - cos)))


def align(reference: np.ndarray, generated: np.ndarray, p: AlignParams = EVERY_FRAME
          ) -> Alignment:
    """The pairing of ``generated`` with ``reference`` under ``p`` (see the module docstring)."""
    if p.rules == "upstream":
        return paper_protocol.align_paper(reference, generated, p)
    if p.rules != "visphy":
        raise ValueError(f"unknown alignment rules {p.rules!r} (visphy or upstream)")
    s = max(1, int(p.sample_every))
    ref_pos = np.arange(0, len(reference), s)
    gen_pos = np.arange(0, len(generated), s)
    if len(ref_pos) == 0 or len(gen_pos) == 0:
        return Alignment(np.zeros(0, int), np.zeros(0, int), method="offset")
    if p.dtw:
        return _dtw(reference[ref_pos], generated[gen_pos], ref_pos, gen_pos, p)
    fr = standardised(gray_features(reference[ref_pos], p.downsample))
    fg = standardised(gray_features(generated[gen_pos], p.downsample))
    nr, ng = len(fr), len(fg)
    need = min(p.min_overlap, nr, ng)
    coarse: list[tuple[float, int]] = []
    for off in range(-p.max_offset, p.max_offset + 1):
        lo, hi = _overlap(nr, ng, off)
        if hi - lo < need:
            continue
        d = fr[lo:hi] - fg[lo + off:hi + off]
        coarse.append((float(np.mean(d * d)), off))
    coarse.sort(key=lambda t: (t[0], abs(t[1]), t[1]))
    refined = []
    for _, off in coarse[:max(1, p.top_k)]:
        cost = _refine_cost(fr, fg, off, p)
        refined.append((cost + p.offset_penalty * abs(off), cost, off))
    refined.sort(key=lambda t: (t[0], abs(t[2]), t[2]))
    _, cost, off = refined[0]
    cost = cost if cost > 1e-12 else 0.0  # float round-off on identical clips
    lo, hi = _overlap(nr, ng, off)
    i = np.arange(lo, hi)
    return Alignment(ref_idx=ref_pos[i], gen_idx=gen_pos[i + off], offset=int(off * s),
                     align_err=cost, method="offset",
                     candidates=[(int(o * s), float(c)) for _, c, o in refined])


def _dtw(ref: np.ndarray, gen: np.ndarray, ref_pos: np.ndarray, gen_pos: np.ndarray,
         p: AlignParams) -> Alignment:
    """Monotone pairing by dynamic time warping (cost: MSE of 48² grayscale features, each
    non-diagonal step penalised by ``dtw_step_penalty``)."""
    fr = standardised(gray_features(ref, p.dtw_size)).astype(np.float64)
    fg = standardised(gray_features(gen, p.dtw_size)).astype(np.float64)
    cost = ((fr * fr).sum(1)[:, None] + (fg * fg).sum(1)[None, :] - 2 * fr @ fg.T) / fr.shape[1]
    cost = np.maximum(cost, 0.0)
    n, m = cost.shape
    acc = np.full((n + 1, m + 1), np.inf)
    acc[0, 0] = 0.0
    step = p.dtw_step_penalty
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            acc[i, j] = cost[i - 1, j - 1] + min(acc[i - 1, j - 1], acc[i - 1, j] + step,
                                                 acc[i, j - 1] + step)
    i, j, path = n, m, []
    while i > 0 and j > 0:
        path.append((i - 1, j - 1))
        moves = [(acc[i - 1, j - 1], i - 1, j - 1), (acc[i - 1, j] + step, i - 1, j),
                 (acc[i, j - 1] + step, i, j - 1)]
        _, i, j = min(moves, key=lambda t: t[0])
    path.reverse()
    ri = np.array([a for a, _ in path])
    gi = np.array([b for _, b in path])
    offsets = gen_pos[gi] - ref_pos[ri]
    return Alignment(ref_idx=ref_pos[ri], gen_idx=gen_pos[gi],
                     offset=int(np.round(np.median(offsets))),
                     align_err=float(np.mean(cost[ri, gi])), method="dtw")
