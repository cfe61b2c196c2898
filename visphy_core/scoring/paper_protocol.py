"""The ``paper`` scoring protocol: upstream's pairing and frame scores, rule by rule.

Upstream is TIGER-AI-Lab/VisPhyWorld, ``utils/evaluate_video_metrics.py``; its
``evaluate_pair(dataset_video, generated_video, sample_every=3)`` (``auto_align`` on, the
defaults ``alignment_max_offset=30``, ``alignment_window=3``, ``alignment_offset_penalty=0.05``)
is what the paper's tables were computed with. Every function here implements one of its rules,
and names the upstream function it follows; none of upstream's code is copied. Its quirks are
kept on purpose: this protocol exists so numbers compare with the paper's. The
time-honest pairings (the ``visphy`` protocol) are `visphy_core.scoring.alignment.align` with
``rules="visphy"``.

The rules, in the order upstream applies them:

1. Frames (``read_video_frames``): every decoded frame in decode order, index ``i`` kept when
   ``i % sample_every == 0``; generated frames stretched to the reference's width×height with
   OpenCV's area interpolation (no aspect kept, no padding). No timestamps are read: a clip at a
   foreign frame rate is paired by index (`sampled_positions`, `fit_to_reference`).
2. Coarse candidates (``_downsample_frame``, ``_coarse_alignment_candidates``): each sampled
   frame as OpenCV grayscale (uint8), area-resized to ``downsample``² (uint8), centred and
   divided by its L2 norm (+1e-8); for every offset in ±min(``max_offset``, longer clip) with
   any overlap, the mean dot product over at most ``max_samples`` positions
   ``linspace(0, overlap − 1, count)`` truncated to integers; the ``top_k`` best (ties: the
   smaller |offset|, then the earlier, i.e. negative, one), plus 0, plus every offset in
   ±min(2, max_offset), always (`coarse_vectors`, `coarse_candidates`).
3. Refinement (``evaluate_pair`` with its ``_stack_frames`` and ``_stack_similarity``): each
   candidate in ascending order is scored on ONE stack of ``window`` consecutive sampled frames
   at the start of the overlap, on raw grayscale intensities in [0, 1] at full resolution (no
   standardisation), cost MSE + 0.5·MAE + 0.1·(1 − cosine) (cosine 0 when a norm product is
   ≤ 1e-8), plus ``offset_penalty``·|offset|; a candidate whose stack does not fit in either
   clip is skipped; the first strictly cheapest wins; none scored: offset 0 and no Align-Err
   (`stack`, `stack_cost`, `refine`).
4. Trim (``evaluate_pair``): both clips cut to the overlap at the chosen offset, then to the
   shorter length (`align_paper`).
5. DTW after the offset step (``_frame_feature``, ``_dtw_align_frames``): on the trimmed clips,
   OpenCV grayscale area-resized to ``dtw_size``² (uint8) / 255, local cost the MSE of the
   features, a non-diagonal step costs ``dtw_step_penalty``; ties: diagonal, then the step from
   the previous reference frame, then the step from the previous generated frame; the path
   traced back from the last pair of both. Every path pair is scored (repeats included). With
   ``dtw`` off (not upstream's default) the trimmed clips are paired index by index
   (`dtw_features`, `dtw_path`).
6. Frame scores (``compute_psnr``, ``compute_ssim``, ``compute_ssim_single_channel``): PSNR on
   all three 8-bit channels, 100 dB when the MSE is ≤ 1e-10 (`visphy_core.api.psnr.psnr` with
   upstream's perfect-match rule; visphy's caps every frame at 100 dB); SSIM as the mean of
   four channels (Y of OpenCV's YCrCb, uint8, and R, G, B), each with OpenCV's 11×11 Gaussian
   blur σ = 1.5 (default border: reflect-101), K1 = 0.01, K2 = 0.03, L = 255, +1e-12 in the
   denominator, averaged over the WHOLE map (no border cropped); per-scene means over the pairs
   that gave a number (``statistics.fmean`` of the non-NaN values) (`psnr`, `ssim`,
   `mean_of_numbers`).

Frames are RGB here (upstream decodes BGR with OpenCV): every conversion uses the matching
RGB code, so each grayscale or Y value is the one upstream computes. Costs are accumulated in
float64 where upstream uses float32; only exact ties could tell them apart, and those come from
identical frames, equal either way.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from visphy_core.api.metrics import Alignment
from visphy_core.api.psnr import PAPER_PERFECT_MSE
from visphy_core.api.psnr import psnr as frame_psnr
from visphy_core.scoring.pairing import AlignParams

#: Where the rules come from.
UPSTREAM = "TIGER-AI-Lab/VisPhyWorld utils/evaluate_video_metrics.py::evaluate_pair"
#: Offsets around 0 that upstream always refines, whatever the coarse search says.
FIXED_RADIUS = 2
#: Identifies this implementation of the rules in cache keys (bump when a rule changes).
RULES_VERSION = "upstream-1"


# ----------------------------------------------------------------------------- 1. frames
def sampled_positions(n_frames: int, sample_every: int) -> np.ndarray:
    """Upstream ``read_video_frames``: decoded frame ``i`` is kept when i % sample_every == 0
    (by index: no timestamps are read)."""
    return np.arange(0, n_frames, max(1, int(sample_every)))


def frames_needed(n_reference: int, sample_every: int, max_offset: int) -> int:
    """How many decoded frames of a generated clip upstream's pairing can ever reach for a
    reference of ``n_reference`` frames: its sampled length plus the widest offset, in decoded
    frames (beyond them the overlap is trimmed away). A caller may keep only these."""
    sampled = -(-n_reference // sample_every)
    return sample_every * (sampled + max_offset + 1)


def fit_to_reference(frames: np.ndarray, height: int, width: int) -> np.ndarray:
    """Upstream ``read_video_frames(resize_to=(w, h))`` of the generated clip: every frame
    stretched to the reference's size by area interpolation (aspect not kept, no padding).
    Frames already at that size are returned as they are."""
    frames = np.asarray(frames)
    if len(frames) == 0 or frames.shape[1:3] == (height, width):
        return frames
    return np.stack([cv2.resize(np.ascontiguousarray(f[..., :3]), (width, height),
                                interpolation=cv2.INTER_AREA) for f in frames])


def _gray(frame: np.ndarray) -> np.ndarray:
    """OpenCV's 8-bit grayscale (the value upstream's BGR→GRAY gives on the same pixel)."""
    return cv2.cvtColor(np.ascontiguousarray(frame[..., :3]), cv2.COLOR_RGB2GRAY)


# ----------------------------------------------------------------------------- 2. coarse
def coarse_vectors(frames: np.ndarray, size: int) -> np.ndarray:
    """Upstream ``_downsample_frame``: 8-bit grayscale, area-resized to size×size (8-bit),
    centred, divided by its L2 norm + 1e-8 (a flat frame: the zero vector). N×size²."""
    out = np.empty((len(frames), size * size), np.float64)
    for k, f in enumerate(frames):
        v = cv2.resize(_gray(f), (size, size), interpolation=cv2.INTER_AREA)
        v = v.reshape(-1).astype(np.float64)
        v -= v.mean()
        out[k] = v / (_norm(v) + 1e-8)
    return out


def coarse_ranking(ref_vecs: np.ndarray, gen_vecs: np.ndarray, max_offset: int,
                   max_samples: int) -> list[tuple[int, float]]:
    """The scoring and ordering inside upstream ``_coarse_alignment_candidates``, in its sign
    convention (offset o > 0 skips o reference frames, o < 0 skips −o generated frames; sampled
    frames): every offset in ±min(``max_offset``, longer clip) with an overlap, as (offset,
    mean correlation over at most ``max_samples`` positions ``linspace(0, overlap − 1)``
    truncated to integers), best first; ties: the smaller |offset|, then the one tried first
    (the negative one)."""
    n_ref, n_gen = len(ref_vecs), len(gen_vecs)
    max_offset = min(max_offset, max(n_ref, n_gen))
    scored: list[tuple[int, float]] = []
    for o in range(-max_offset, max_offset + 1):
        r0, g0 = max(0, o), max(0, -o)
        overlap = min(n_ref - r0, n_gen - g0)
        count = min(max_samples, overlap)
        if overlap <= 0 or count <= 0:
            continue
        at = np.linspace(0, overlap - 1, count, dtype=int)  # truncated, as upstream
        corr = np.einsum("ij,ij->i", ref_vecs[r0 + at], gen_vecs[g0 + at])
        scored.append((o, float(np.mean(corr))))
    return sorted(scored, key=lambda t: (-t[1], abs(t[0])))  # stable: ties keep try order


def coarse_candidates(ref_vecs: np.ndarray, gen_vecs: np.ndarray, max_offset: int,
                      max_samples: int, top_k: int) -> list[int]:
    """Upstream ``_coarse_alignment_candidates``: the ``top_k`` offsets of `coarse_ranking`,
    plus 0, plus every offset within ±min(2, max_offset) whatever their correlation (the
    fixed small candidates), ascending; [0] when there is nothing to search."""
    if max_offset <= 0 or len(ref_vecs) == 0 or len(gen_vecs) == 0:
        return [0]
    ranked = coarse_ranking(ref_vecs, gen_vecs, max_offset, max_samples)
    if not ranked:
        return [0]
    max_offset = min(max_offset, max(len(ref_vecs), len(gen_vecs)))
    picked = {int(np.clip(o, -max_offset, max_offset)) for o, _ in ranked[:top_k]} | {0}
    radius = min(FIXED_RADIUS, max_offset)
    return sorted(picked | set(range(-radius, radius + 1)))


# ----------------------------------------------------------------------------- 3. refinement
def stack(gray: list[np.ndarray], start: int, window: int) -> np.ndarray:
    """Upstream ``evaluate_pair._stack_frames``: ``window`` consecutive sampled frames from
    ``start`` (the last repeated if the clip ends first), raw grayscale in [0, 1]."""
    part = gray[start:start + window]
    part = part + [part[-1]] * (window - len(part))
    return np.stack(part).astype(np.float64) / 255.0


def _norm(v: np.ndarray) -> float:
    """The L2 norm by numpy's own pairwise sum, never BLAS: BLAS splits long dot products
    across its threads, so the last bits would depend on the thread count (a Ray or joblib
    worker runs with one thread) and the same clips would not give the same scores."""
    return float(np.sqrt(np.sum(v * v)))


def stack_cost(a: np.ndarray, b: np.ndarray) -> float:
    """Upstream ``evaluate_pair._stack_similarity``: MSE + 0.5·MAE + 0.1·(1 − cosine) of two
    stacks as they are (no centring, no scaling); cosine 0 when the norm product is ≤ 1e-8."""
    d = a - b
    mse = float(np.mean(d * d))
    mae = float(np.mean(np.abs(d)))
    fa, fb = a.reshape(-1), b.reshape(-1)
    # ‖a‖·‖b‖ as √(Σa²·Σb²): exactly Σa² for identical stacks, so their cosine is exactly 1
    denom = math.sqrt(float(np.sum(fa * fa)) * float(np.sum(fb * fb)))
    cos = float(np.clip(float(np.sum(fa * fb)) / denom, -1.0, 1.0)) if denom > 1e-8 else 0.0
    return mse + 0.5 * mae + 0.1 * (1.0 - cos)


def refine(ref: np.ndarray, gen: np.ndarray, candidates: list[int], window: int,
           offset_penalty: float) -> tuple[int, int, float, list[tuple[int, float]]]:
    """Upstream ``evaluate_pair``'s offset loop: each candidate (ascending) scored on one
    stack at the start of its overlap; the first strictly cheapest with the penalty wins.
    Returns (reference start, generated start, cost without penalty (NaN: none scored), every
    scored (offset, cost)), starts and offsets in sampled frames, upstream's sign."""
    window = max(1, int(window))
    gray_ref: dict[int, np.ndarray] = {}
    gray_gen: dict[int, np.ndarray] = {}

    def grays(frames: np.ndarray, memo: dict, start: int) -> list[np.ndarray]:
        for k in range(start, start + window):
            if k not in memo:
                memo[k] = _gray(frames[k])
        return [memo[k] for k in range(start, start + window)]

    best, best_cost, best_pair = math.inf, math.nan, (0, 0)
    scored: list[tuple[int, float]] = []
    for o in candidates:
        r0, g0 = max(0, o), max(0, -o)
        if r0 + window > len(ref) or g0 + window > len(gen):
            continue
        cost = stack_cost(stack(grays(ref, gray_ref, r0), 0, window),
                          stack(grays(gen, gray_gen, g0), 0, window))
        scored.append((o, cost))
        if cost + abs(o) * offset_penalty < best:
            best, best_cost, best_pair = cost + abs(o) * offset_penalty, cost, (r0, g0)
    return best_pair[0], best_pair[1], best_cost, scored


# ----------------------------------------------------------------------------- 5. DTW
def dtw_features(frames: np.ndarray, size: int) -> np.ndarray:
    """Upstream ``_frame_feature``: 8-bit grayscale area-resized to size×size (8-bit), / 255."""
    return np.stack([cv2.resize(_gray(f), (size, size), interpolation=cv2.INTER_AREA)
                     .reshape(-1) for f in frames]).astype(np.float64) / 255.0


def dtw_path(ref_feats: np.ndarray, gen_feats: np.ndarray, step_penalty: float
             ) -> tuple[list[tuple[int, int]], float]:
    """Upstream ``_dtw_align_frames``: the monotone path from (0, 0) to (n−1, m−1) of least
    summed local MSE, each non-diagonal step costing ``step_penalty``; at each cell the first
    cheapest of (diagonal, from the previous reference frame, from the previous generated
    frame) is kept, and the path is read back from the last cell. Returns (path, its cost)."""
    n, m = len(ref_feats), len(gen_feats)
    if n == 0 or m == 0:
        return [], 0.0
    local = np.empty((n, m), np.float64)
    for i in range(n):
        d = gen_feats - ref_feats[i]
        local[i] = np.mean(d * d, axis=1)
    acc = np.full((n, m), np.inf)
    back = np.full((n, m, 2), -1, np.int64)
    for i in range(n):
        for j in range(m):
            if i == 0 and j == 0:
                acc[0, 0] = local[0, 0]
                continue
            best, frm = math.inf, (-1, -1)
            for pi, pj, pen in ((i - 1, j - 1, 0.0), (i - 1, j, step_penalty),
                                (i, j - 1, step_penalty)):
                if pi < 0 or pj < 0:
                    continue
                if acc[pi, pj] + pen < best:  # strict: the first cheapest in this order
                    best, frm = acc[pi, pj] + pen, (pi, pj)
            acc[i, j] = local[i, j] + best
            back[i, j] = frm
    path, i, j = [], n - 1, m - 1
    while i >= 0 and j >= 0:
        path.append((i, j))
        i, j = (int(v) for v in back[i, j])
    path.reverse()
    total = float(acc[n - 1, m - 1])
    return path, total if math.isfinite(total) else math.inf


# ----------------------------------------------------------------------------- the pairing
def align_paper(reference: np.ndarray, generated: np.ndarray, p: AlignParams) -> Alignment:
    """Upstream ``evaluate_pair``'s pairing of ``generated`` (already `fit_to_reference`, frames
    in decode order) with ``reference``: sampling, coarse candidates, one-stack refinement,
    trim, then DTW (module docstring, rules 1–5). Indices are frames of the input clips;
    ``offset`` is generated − reference at the offset step (visphy's sign), ``align_err`` the
    refinement cost there without the penalty (NaN: no candidate fitted)."""
    s = max(1, int(p.sample_every))
    ref_pos = sampled_positions(len(reference), s)
    gen_pos = sampled_positions(len(generated), s)
    if len(ref_pos) == 0 or len(gen_pos) == 0:
        empty = np.zeros(0, int)
        return Alignment(empty, empty.copy(), method="offset", align_err=math.nan)
    ref, gen = reference[::s], generated[::s]  # views: the frames at ref_pos, gen_pos
    candidates = coarse_candidates(coarse_vectors(ref, p.downsample),
                                   coarse_vectors(gen, p.downsample),
                                   max(0, int(p.max_offset)), int(p.max_samples), int(p.top_k))
    r0, g0, cost, scored = refine(ref, gen, candidates, p.window, p.offset_penalty)
    n = min(len(ref) - r0, len(gen) - g0)
    if p.dtw:
        path, _ = dtw_path(dtw_features(ref[r0:r0 + n], p.dtw_size),
                           dtw_features(gen[g0:g0 + n], p.dtw_size), p.dtw_step_penalty)
        ri = np.array([i for i, _ in path], dtype=int)
        gi = np.array([j for _, j in path], dtype=int)
    else:
        ri = gi = np.arange(n)
    return Alignment(ref_idx=ref_pos[r0 + ri], gen_idx=gen_pos[g0 + gi],
                     offset=int((g0 - r0) * s), align_err=float(cost),
                     method="dtw" if p.dtw else "offset",
                     candidates=[(int(-o * s), float(c)) for o, c in scored])


# ----------------------------------------------------------------------------- 6. scores
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Upstream ``compute_psnr``: over all three 8-bit channels, 100 dB at MSE ≤ 1e-10 (the
    one PSNR with upstream's perfect-match rule)."""
    return frame_psnr(a, b, PAPER_PERFECT_MSE)


_C1, _C2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2


def ssim_channel(x: np.ndarray, y: np.ndarray) -> float:
    """Upstream ``compute_ssim_single_channel``: float32, OpenCV Gaussian blur 11×11 σ = 1.5
    with its default border (reflect-101), +1e-12 in the denominator, the whole map's mean."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    y = np.ascontiguousarray(y, dtype=np.float32)

    def blur(z: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(z, (11, 11), 1.5)

    mx, my = blur(x), blur(y)
    mxx, myy, mxy = mx * mx, my * my, mx * my
    sxx = blur(x * x) - mxx
    syy = blur(y * y) - myy
    sxy = blur(x * y) - mxy
    num = (2 * mxy + _C1) * (2 * sxy + _C2)
    den = (mxx + myy + _C1) * (sxx + syy + _C2) + 1e-12
    return float((num / den).mean())


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Upstream ``compute_ssim``: the mean of Y (OpenCV YCrCb, 8-bit), R, G and B SSIM."""
    a = np.ascontiguousarray(a[..., :3])
    b = np.ascontiguousarray(b[..., :3])
    ya = cv2.cvtColor(a, cv2.COLOR_RGB2YCrCb)[..., 0]
    yb = cv2.cvtColor(b, cv2.COLOR_RGB2YCrCb)[..., 0]
    s_y = ssim_channel(ya, yb)
    s_r, s_g, s_b = (ssim_channel(a[..., c], b[..., c]) for c in (0, 1, 2))
    return float((s_y + s_r + s_g + s_b) / 4.0)


#: The frame scores upstream computes itself (by visphy metric name); every other pair metric
#: runs visphy's implementation on the paper's pairs.
FRAME_SCORES = {"psnr": psnr, "ssim": ssim}
#: A frame score that fails with these counts as NaN, left out of the mean (upstream's
#: ``evaluate_pair`` catches OpenCV's error around SSIM).
FRAME_SCORE_ERRORS = (cv2.error,)


def mean_of_numbers(values) -> float:
    """Upstream's per-scene mean (``statistics.fmean`` of the values that are not NaN; NaN when
    none is)."""
    kept = [float(v) for v in values if not math.isnan(float(v))]
    return math.fsum(kept) / len(kept) if kept else math.nan
