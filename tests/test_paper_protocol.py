"""The ``paper`` protocol follows upstream's ``utils/evaluate_video_metrics.py::evaluate_pair``
rule by rule (`visphy_core.scoring.paper_protocol`), while the ``visphy`` pairings stay time-honest.

Each test is built on a synthetic clip where the upstream rule and visphy's own rule give
different answers, and asserts upstream's: implemented the visphy way, it fails. Clips are
built in sampled frames and expanded ×3 (`expand`), so upstream's every-3rd-frame sampling
sees exactly the sequence built; offsets in assertions are in frames of the input clips,
visphy's sign (generated = reference + offset)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from visphy_core.api.scene import ClipInfo, Scene
from visphy_core.infra.cache import Cache
from visphy_core.scoring import paper_protocol as pp
from visphy_core.scoring.alignment import PAPER, AlignParams, align
from visphy_core.scoring.score import ScoringProtocol, score_scene
from visphy_plugins.metrics.pixel import PSNR, SSIM, psnr_frame, ssim_frame

SIZE = 96


def expand(seq: np.ndarray, every: int = 3) -> np.ndarray:
    """Each frame held ``every`` frames: sampling every ``every``-th frame gives ``seq`` back."""
    return np.repeat(seq, every, axis=0)


def noise(n: int, seed: int) -> np.ndarray:
    """Every frame its own texture: any wrong pairing costs a lot, raw or standardised."""
    return np.random.default_rng(seed).integers(0, 256, (n, SIZE, SIZE, 3), dtype=np.uint8)


def squares(n: int) -> np.ndarray:
    """A small red square crossing a white frame, 2 px a frame: the kind of scene where raw
    intensities differ little between neighbouring frames."""
    f = np.full((n, SIZE, SIZE, 3), 255, np.uint8)
    for t in range(n):
        f[t, 40:50, 5 + 2 * t:15 + 2 * t] = (200, 30, 30)
    return f


def blobs(first: int, n: int) -> np.ndarray:
    """A soft grey blob drifting 3 px a frame: neighbouring frames correlate strongly, frames
    nine apart hardly at all."""
    yy, xx = np.mgrid[:SIZE, :SIZE]
    out = []
    for t in range(first, first + n):
        cx, cy = (10 + 3.0 * t) % SIZE, SIZE / 2 + 20 * np.sin(t / 5)
        g = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * 8.0 ** 2))
        out.append(np.repeat((255 * (1 - 0.8 * g)).astype(np.uint8)[..., None], 3, axis=2))
    return np.stack(out)


def scene_for(n: int, fps: float = 10.0) -> Scene:
    return Scene(scene_id="s0", dim="2d", clip=ClipInfo(fps=fps, n_frames=n, width=SIZE,
                                                        height=SIZE), video_path=Path("none.mp4"))


def grey(frames: np.ndarray) -> np.ndarray:
    """Raw grey levels in [0, 1], as upstream's stacks hold them."""
    return np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]) / 255.0


def standardised_stack(frames: np.ndarray) -> np.ndarray:
    """visphy's refinement features: each grayscale frame at zero mean and unit variance."""
    g = np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]).astype(np.float64)
    g = g.reshape(len(g), -1)
    return (g - g.mean(1, keepdims=True)) / g.std(1, keepdims=True)


# ----------------------------------------------------------------------------- offset step
def test_refinement_on_raw_intensities_keeps_offset_zero():
    """Rule: ``_stack_similarity`` on raw grey levels. A small square 6 frames late: on raw
    intensities offset 0 costs ~0.01, under the penalty of 2 sampled frames (0.1), so upstream
    keeps 0; standardised frames make the same mismatch cost ~1.1 and would pick +6."""
    ref = squares(30)
    late = ref[np.clip(np.arange(30) - 6, 0, 29)]
    r, g = ref[::3], late[::3]
    _, _, cost0, _ = pp.refine(r, g, [0], 3, 0.05)
    assert cost0 < 0.1  # raw: cheaper than the penalty of the true offset
    standardised0 = pp.stack_cost(standardised_stack(r[:3]), standardised_stack(g[:3]))
    assert standardised0 > 0.5  # the visphy way: far dearer, offset -2 (cost 0 + 0.1) wins
    assert align(ref, late, PAPER).offset == 0
    assert align(ref, late, AlignParams(sample_every=3)).offset == 6  # visphy's rules


def test_stack_cost_reads_intensities_as_they_are():
    """Flat stacks: standardising would make every flat frame the zero vector (cost 0); upstream
    compares the grey levels, and a zero norm product counts as cosine 0."""
    half, one, zero = (np.full((3, 8, 8), v) for v in (0.5, 1.0, 0.0))
    assert pp.stack_cost(half, one) == pytest.approx(0.25 + 0.5 * 0.5)  # cosine 1
    assert pp.stack_cost(one, zero) == pytest.approx(1 + 0.5 + 0.1)    # cosine 0 (no norm)
    assert pp.stack_cost(one, one) == pytest.approx(0.0, abs=1e-12)


def test_fixed_small_candidates_are_always_refined():
    """Rule: ``_coarse_alignment_candidates`` adds 0, ±1, ±2 whatever the correlation. Here the
    first three sampled frames match at +1 (reference skips one) and the rest at +10: the
    coarse top 5 is 8…12, yet upstream refines +1 on its start stack (cost 0 + 0.05) and keeps
    it; refining only the top 5 would end near +10."""
    r = np.concatenate([noise(4, seed=1), blobs(4, 36)])
    g = np.concatenate([r[1:4], r[13:40]])
    rv, gv = pp.coarse_vectors(r, 64), pp.coarse_vectors(g, 64)
    top = [o for o, _ in pp.coarse_ranking(rv, gv, 30, 16)[:5]]
    assert sorted(top) == [8, 9, 10, 11, 12]
    assert pp.coarse_candidates(rv, gv, 30, 16, 5) == [-2, -1, 0, 1, 2, 8, 9, 10, 11, 12]
    a = align(expand(r), expand(g), PAPER)
    assert a.offset == -3  # upstream +1 sampled frame: generated = reference − 3 frames
    assert a.align_err == pytest.approx(0.0, abs=1e-12)
    assert {-6, -3, 0, 3, 6} <= {o for o, _ in a.candidates}


def test_one_three_frame_stack_decides_the_offset():
    """Rule: ``evaluate_pair`` refines each candidate on ONE stack of 3 sampled frames at the
    start of the overlap. The first 3 frames match at 0, all later ones at +2 (reference skips
    two): spread over 16 positions +2 would win; upstream's single start stack keeps 0."""
    r = noise(30, seed=5)
    g = np.concatenate([r[:3], r[5:30]])
    ref_start, gen_start, cost, scored = pp.refine(r, g, [0, 2], 3, 0.05)
    assert (ref_start, gen_start, cost) == (0, 0, 0.0)
    late = dict(scored)[2]
    assert late > 0.15  # +2 on the start stack: noise against noise
    spread = np.mean([pp.stack_cost(grey(r[2 + t:5 + t]), grey(g[t:t + 3]))
                      for t in range(3, 24, 2)])
    assert spread == pytest.approx(0.0, abs=1e-12)  # later, +2 matches exactly: a search over
    # positions spread through the clip would take it
    assert align(expand(r), expand(g), PAPER).offset == 0


def test_coarse_ties_prefer_small_then_negative_offsets_and_the_range_is_clamped():
    """Rule: ``_coarse_alignment_candidates`` sorts by correlation, then smaller |offset|, and
    keeps the order tried (negative first) among equals; max_offset is cut to the longer clip
    and the fixed candidates to ±min(2, max_offset)."""
    flat = np.zeros((6, 16))  # flat frames: zero vectors, every correlation 0
    ranked = [o for o, _ in pp.coarse_ranking(flat, flat, 30, 16)]
    assert ranked[:5] == [0, -1, 1, -2, 2] and len(ranked) == 11  # ±min(30, 6) with overlap
    assert pp.coarse_candidates(flat[:2], flat[:1], 30, 16, 5) == [-2, -1, 0, 1, 2]
    assert pp.coarse_candidates(flat, flat, 1, 16, 5) == [-1, 0, 1]
    assert pp.coarse_candidates(flat, flat, 0, 16, 5) == [0]


def test_a_clip_too_short_for_a_stack_has_offset_zero_and_no_align_err(tmp_path):
    """Rule: a candidate whose 3-frame stack does not fit is skipped; none fits: offset 0, no
    Align-Err (upstream's NaN), and the pairs still come from DTW."""
    clip = squares(4)  # 2 sampled frames
    scores, _ = score_scene(scene_for(4), clip, clip[::-1].copy(), [PSNR()], None, None,
                            Cache(tmp_path / "c"))
    assert scores["paper.align.offset"] == 0 and scores["paper.align.err"] is None
    assert scores["paper.psnr"] is not None


# ----------------------------------------------------------------------------- DTW
def test_dtw_runs_after_the_offset_step_on_the_trimmed_clips():
    """Rule: ``evaluate_pair`` trims both clips at the chosen offset, then ``_dtw_align_frames``
    warps what is left. A clip 2 sampled frames late (its own lead-in) with one frame held in
    the middle: the path starts at the offset (0, 6), not at (0, 0) as a DTW replacing the
    offset step would, and steps over the held frame, which an offset alone cannot."""
    r = noise(20, seed=7)
    g = np.concatenate([noise(2, seed=8), r[:10], r[9:10], r[10:]])
    ref, gen = expand(r), expand(g)
    a = align(ref, gen, PAPER)
    assert a.method == "dtw" and a.offset == 6
    assert a.pairs()[0] == (0, 6)
    assert (27, 33) in a.pairs() and (27, 36) in a.pairs()  # the held frame, paired twice
    # every pair shows the same frame but the forced last one (the trimmed clips' ends)
    assert all(np.array_equal(ref[i], gen[j]) for i, j in a.pairs()[:-1])
    assert not np.array_equal(ref[a.ref_idx[-1]], gen[a.gen_idx[-1]])
    replacing = align(ref, gen, AlignParams(sample_every=3, dtw=True))  # visphy's DTW
    assert replacing.pairs()[0] == (0, 0)
    offset_only = align(ref, gen, AlignParams(sample_every=3, dtw=False, rules="upstream"))
    assert np.all(np.diff(offset_only.gen_idx) == 3)  # no warp: the held frame is missed


def test_dtw_features_are_raw_grey_levels():
    """Rule: ``_frame_feature`` is grey / 255 (not standardised). Flat frames of different
    greys: standardised they would all be the zero vector and every path cost the same."""
    greys = [10, 120, 240]
    ref = np.stack([np.full((SIZE, SIZE, 3), v, np.uint8) for v in greys])
    gen = np.stack([np.full((SIZE, SIZE, 3), v, np.uint8) for v in (10, 10, 120, 240, 240)])
    path, cost = pp.dtw_path(pp.dtw_features(ref, 48), pp.dtw_features(gen, 48), 0.005)
    assert path == [(0, 0), (0, 1), (1, 2), (2, 3), (2, 4)]
    assert cost == pytest.approx(2 * 0.005)


def test_dtw_ties_go_diagonal_first():
    """Rule: ``_dtw_align_frames`` keeps the first cheapest of (diagonal, previous reference
    frame, previous generated frame)."""
    same = np.zeros((3, 4))
    path, cost = pp.dtw_path(same[:2], same, 0.005)
    assert path == [(0, 0), (0, 1), (1, 2)]
    assert cost == pytest.approx(0.005)


# ----------------------------------------------------------------------------- frames
def test_a_foreign_frame_rate_is_paired_by_index_under_paper_by_time_under_visphy(tmp_path):
    """Rule: ``read_video_frames`` reads no timestamps. The scene's 30 frames played at
    35 fps: by index they ARE the reference (paper: 100 dB); by time they run 3.5× fast."""
    n = 30
    ref = squares(n)
    scores, _ = score_scene(scene_for(n), ref, ref.copy(), [PSNR()], None, None,
                            Cache(tmp_path / "c"), generated_times_s=np.arange(n) / 35.0)
    assert scores["paper.psnr"] == 100.0 and scores["paper.align.offset"] == 0
    assert scores["psnr"] < 40  # visphy: paired by time, the clip is too fast


def test_a_high_frame_rate_clip_is_right_by_time_and_wrong_by_index(tmp_path):
    """The same rule the other way: the reference shown at 125 fps (each frame ~12.5 times).
    By time (visphy) it is the reference exactly; by index (paper) the first 30 sampled
    frames cover its first 7 frames only, held against the whole reference."""
    n = 30
    ref = squares(n)
    k = np.arange(int(n * 12.5))
    fast = ref[np.minimum(np.rint(k / 12.5).astype(int), n - 1)]
    scores, _ = score_scene(scene_for(n), ref, fast, [PSNR(), SSIM()], None, None,
                            Cache(tmp_path / "c"), generated_times_s=k / 125.0)
    assert scores["psnr"] == 100.0 and scores["ssim"] == pytest.approx(1.0)
    assert scores["paper.psnr"] < 40 and scores["paper.ssim"] < 0.99


def test_a_different_size_is_stretched_not_padded(tmp_path):
    """Rule: ``read_video_frames(resize_to=(w, h))``: area interpolation to the reference's
    size, aspect not kept. The reference stretched to 2:1: stretched back it is the reference
    again; visphy fits it inside with white bars (aspect kept)."""
    ref = squares(30)
    wide = np.stack([cv2.resize(f, (2 * SIZE, SIZE), interpolation=cv2.INTER_AREA)
                     for f in ref])
    scores, _ = score_scene(scene_for(30), ref, wide, [PSNR()], None, None,
                            Cache(tmp_path / "c"))
    assert scores["paper.psnr"] == 100.0
    assert scores["psnr"] < 40


def test_every_third_decoded_frame_from_the_first():
    assert pp.sampled_positions(10, 3).tolist() == [0, 3, 6, 9]
    a = align(squares(31), squares(31), PAPER)
    assert a.pairs() == [(i, i) for i in range(0, 31, 3)]


# ----------------------------------------------------------------------------- static
def test_the_frozen_first_frame_is_scored_at_offset_zero(tmp_path):
    """``static`` (the first frame held) under upstream's rules: offset 0 (every other offset
    costs the same stack plus a penalty, or more), DTW keeps the diagonal (a frozen clip offers
    no cheaper path), so its PSNR is the mean over ALL sampled frames against frame 0. visphy's
    rules would shift it to the frames near the start, where frozen matches best."""
    n = 45
    ref = squares(n)
    frozen = np.repeat(ref[:1], n, axis=0)
    scores, _ = score_scene(scene_for(n), ref, frozen, [PSNR()], None, None,
                            Cache(tmp_path / "c"))
    upstream = np.mean([pp.psnr(ref[r], ref[0]) for r in range(0, n, 3)])
    assert scores["paper.align.offset"] == 0
    assert scores["paper.psnr"] == pytest.approx(upstream, abs=1e-9)
    flattered = align(ref, frozen, AlignParams(sample_every=3))  # visphy's rules
    assert flattered.offset != 0
    flattered_psnr = np.mean([pp.psnr(ref[r], frozen[g]) for r, g in flattered.pairs()])
    assert flattered_psnr > scores["paper.psnr"] + 3


# ----------------------------------------------------------------------------- frame scores
def test_psnr_is_not_capped_below_upstreams_threshold():
    """Rule: ``compute_psnr`` caps at 100 dB only for MSE ≤ 1e-10: one level off in one value
    of a 256² frame is 101.07 dB upstream (visphy's PSNR caps there at 100)."""
    a = np.full((256, 256, 3), 128, np.uint8)
    b = a.copy()
    b[100, 100, 0] = 129
    expect = 10 * np.log10(255.0 ** 2 * a.size)
    assert pp.psnr(a, b) == pytest.approx(expect) == pytest.approx(101.0668, abs=1e-3)
    assert psnr_frame(a, b) == 100.0
    assert pp.psnr(a, a) == 100.0


def _full_map_ssim(x: np.ndarray, y: np.ndarray, crop: int = 0) -> float:
    """Single-channel SSIM with a mirror-border (reflect-101) Gaussian, σ = 1.5, radius 5."""
    x, y = x.astype(np.float64), y.astype(np.float64)

    def blur(z):
        return gaussian_filter(z, 1.5, mode="mirror", truncate=5 / 1.5)

    mx, my = blur(x), blur(y)
    sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return float(m[crop:m.shape[0] - crop, crop:m.shape[1] - crop].mean())


def test_ssim_averages_the_whole_map_with_a_reflect101_border():
    """Rule: ``compute_ssim_single_channel``: OpenCV GaussianBlur's default border, the whole
    map averaged (visphy crops the filter radius). A difference along the top edge."""
    rng = np.random.default_rng(3)
    x = rng.integers(60, 200, (64, 64)).astype(np.uint8)
    y = x.copy()
    y[:4] = 255 - y[:4]
    full, cropped = _full_map_ssim(x, y), _full_map_ssim(x, y, crop=5)
    assert pp.ssim_channel(x, y) == pytest.approx(full, abs=1e-5)
    assert abs(full - cropped) > 0.02  # the border matters here
    # grey frames: Y = R = G = B, so the four-channel mean is the channel's SSIM
    a, b = (np.repeat(c[..., None], 3, axis=2) for c in (x, y))
    assert pp.ssim(a, b) == pytest.approx(full, abs=1e-5)
    assert ssim_frame(a, b) == pytest.approx(cropped, abs=1e-4)


def test_a_failed_frame_score_is_left_out_of_the_mean():
    """Rule: ``evaluate_pair`` averages the frame scores that are not NaN."""
    assert pp.mean_of_numbers([1.0, float("nan"), 3.0]) == 2.0
    assert np.isnan(pp.mean_of_numbers([float("nan")]))


# ----------------------------------------------------------------------------- the views
def test_visphy_pairings_are_unchanged_and_paper_columns_use_upstreams_scores(tmp_path):
    """The visphy columns keep visphy's PSNR on time-paired frames; the paper column is
    upstream's PSNR over exactly the paper pairing's pairs."""
    n = 30
    ref = squares(n)
    gen = ref[np.clip(np.arange(n) - 4, 0, n - 1)]
    scores, _ = score_scene(scene_for(n), ref, gen, [PSNR(), SSIM()], None, None,
                            Cache(tmp_path / "c"))
    assert scores["psnr"] == pytest.approx(np.mean([psnr_frame(a, b) for a, b in zip(ref, gen)]))
    assert scores["align.offset"] == 4 and scores["psnr.aligned"] == 100.0
    paper = align(ref, gen, PAPER)
    assert scores["paper.psnr"] == pytest.approx(
        np.mean([pp.psnr(ref[r], gen[g]) for r, g in paper.pairs()]))
    assert scores["paper.ssim"] == pytest.approx(
        np.mean([pp.ssim(ref[r], gen[g]) for r, g in paper.pairs()]))
    only_visphy, _ = score_scene(scene_for(n), ref, gen, [PSNR()], None, None,
                                 Cache(tmp_path / "d"), protocol=ScoringProtocol(paper=False))
    assert only_visphy["psnr.aligned"] == scores["psnr.aligned"]
    assert not any(k.startswith("paper.") for k in only_visphy)


def test_the_paper_rules_are_the_protocols_default_and_dtw_runs_after_the_offset():
    from visphy_core.config.check import check_overrides

    assert PAPER.rules == "upstream" and PAPER.dtw and PAPER.sample_every == 3
    (cfg,) = check_overrides([])
    p = ScoringProtocol.from_cfg(cfg.metrics)
    assert p.paper_params.rules == "upstream" and p.paper_params.dtw
    assert p.aligned_params.rules == "visphy" and not p.aligned_params.dtw
    (cfg,) = check_overrides(["metrics.paper.dtw=false"])
    assert not ScoringProtocol.from_cfg(cfg.metrics).paper_params.dtw


def test_a_replayed_video_at_a_foreign_rate_is_paired_by_index_in_a_run(tmp_path):
    """End to end: a video model's reply at 35 fps (the ground truth's frames, encoded at the
    wrong rate) goes through `load_clip_for` (time-resampled for visphy's pairing) while the
    paper view pairs the reply's own decoded frames by index, as upstream reads the file: the
    paper PSNR is that of the truth against itself, visphy's that of a clip 7× too fast."""
    import json

    from conftest import run_cli
    from visphy_core.infra.video import decode_video, encode_video
    from visphy_plugins.datasets.tiny import make_tiny_dataset

    root = make_tiny_dataset(tmp_path / "data", 1)
    truth_path = next((root / "sub" / "videos").glob("*.mp4"))
    truth, info = decode_video(truth_path)
    replies = tmp_path / "replies"
    replies.mkdir()
    encode_video(truth, replies / truth_path.name, 35.0)
    home = tmp_path / "home"
    run_cli("model=replay", f"model.source={replies}", "model.output=video",
            "dataset=original", f"dataset.root={root}", "metrics.names=[psnr]",
            "metrics.spec_track=false", "metrics.variance_norm=false", "tracking=none",
            "run.progress=false", home=home)
    run_dir = next((home / "runs").iterdir())
    row = json.loads((run_dir / "results.jsonl").read_text().splitlines()[0])
    assert info.fps != 35.0
    assert row["score_paper.psnr"] > 35 and row["score_paper.align.offset"] == 0
    assert row["score_psnr"] < row["score_paper.psnr"] - 5


def test_paper_costs_do_not_depend_on_the_blas_thread_count():
    """A Ray or joblib job runs with one BLAS thread: the same clips must give the same bits
    (BLAS splits long dot products across threads; the costs use numpy's own sums)."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(3)
    a = rng.random((3, 512, 512)) * 0.5
    b = a + rng.normal(0, 0.01, a.shape)
    ref = (rng.random((40, 64, 64, 3)) * 255).astype(np.uint8)
    with threadpool_limits(limits=1):
        one = (pp.stack_cost(a, b), pp.psnr(ref[0], ref[1]), pp.coarse_vectors(ref, 64))
    many = (pp.stack_cost(a, b), pp.psnr(ref[0], ref[1]), pp.coarse_vectors(ref, 64))
    assert one[0] == many[0] and one[1] == many[1] and np.array_equal(one[2], many[2])
