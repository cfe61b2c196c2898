"""Temporal alignment (`visphy_core.scoring.alignment`) and the scoring protocols built on it
(`visphy_core.scoring.score`): injected offsets are recovered exactly, identical clips align at 0
with
Align-Err 0, and each pairing's columns are the means over exactly its pairs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from visphy_core.api.metrics import LOWER, SCENE, Metric, MetricInput
from visphy_core.api.scene import ClipInfo, Scene
from visphy_core.config.check import ConfigError, check_overrides
from visphy_core.infra.cache import Cache
from visphy_core.scoring import paper_protocol
from visphy_core.scoring.alignment import (
    EVERY_FRAME,
    PAPER,
    AlignParams,
    align,
    gray_features,
    unaligned,
)
from visphy_core.scoring.score import ScoringProtocol, score_columns, score_scene
from visphy_plugins.metrics.pixel import PSNR, SSIM, psnr_frame


def moving_clip(n: int, size: int = 96, seed: int = 0) -> np.ndarray:
    """A white clip with a red square on a curved path and a blue one drifting: every frame
    differs from every other."""
    rng = np.random.default_rng(seed)
    frames = np.full((n, size, size, 3), 255, np.uint8)
    x0, y0 = rng.integers(5, 20, size=2)
    for t in range(n):
        x = int(x0 + t * (size - 30) / n)
        y = int(y0 + 0.03 * t * t) % (size - 12)
        frames[t, y:y + 10, x:x + 10] = (200, 30, 30)
        bx = int(size - 20 - t * 0.5) % (size - 8)
        frames[t, size - 15:size - 7, bx:bx + 8] = (30, 30, 200)
    return frames


def delayed(clip: np.ndarray, k: int) -> np.ndarray:
    """The clip shifted by k frames (k > 0: later), its ends held: reference frame r appears at
    generated frame r + k, so the offset to find is +k."""
    n = len(clip)
    return clip[np.clip(np.arange(n) - k, 0, n - 1)]


# ----------------------------------------------------------------------------- alignment


@pytest.mark.parametrize("n, k", [(n, k) for n in (17, 40) for k in range(-10, 11)
                                  if n - abs(k) >= EVERY_FRAME.min_overlap])  # overlap left
def test_every_frame_search_recovers_injected_offsets_exactly(n, k):
    ref = moving_clip(n)
    a = align(ref, delayed(ref, k), EVERY_FRAME)
    assert a.offset == k
    assert a.method == "offset"
    assert np.all(a.gen_idx - a.ref_idx == k)
    assert a.align_err == pytest.approx(0.0, abs=1e-9)  # the overlap matches exactly


def textured_clip(n: int, size: int = 96, seed: int = 0) -> np.ndarray:
    """Every frame its own noise texture: a wrong pairing costs far more than any offset
    penalty, on raw intensities too."""
    return np.random.default_rng(seed).integers(0, 256, size=(n, size, size, 3), dtype=np.uint8)


@pytest.mark.parametrize("k", [-9, -6, -3, 0, 3, 6, 9])
def test_paper_search_on_every_third_frame_recovers_offsets(k):
    # upstream's rules (visphy_core.scoring.paper_protocol): recovered where the raw cost of a wrong
    # pairing exceeds the penalty; small objects on white are not (tests/test_paper_protocol.py)
    ref = textured_clip(75, seed=3)
    gen = delayed(ref, k)
    gen[:max(k, 0)] = textured_clip(max(k, 0), seed=4)  # a lead-in of its own, not a hold
    a = align(ref, gen, PAPER)
    assert a.offset == k
    assert np.all(a.ref_idx % 3 == 0) and np.all(a.gen_idx % 3 == 0)
    tried = [o for o, _ in a.candidates]
    assert {k, 0, -3, 3, -6, 6} <= set(tried)  # 0, ±1, ±2 sampled frames always refined
    assert len(tried) <= PAPER.top_k + 5


@pytest.mark.parametrize("params", [EVERY_FRAME, PAPER, AlignParams(sample_every=3, dtw=True)])
def test_identical_clips_align_at_zero_with_zero_error(params):
    ref = moving_clip(30, seed=1)
    a = align(ref, ref.copy(), params)
    assert a.offset == 0 and a.align_err == pytest.approx(0.0, abs=1e-12)
    assert np.array_equal(a.ref_idx, a.gen_idx)
    assert a.ref_idx[0] == 0


def test_a_still_clip_prefers_no_offset():
    still = np.repeat(moving_clip(1)[:1], 20, axis=0)
    a = align(still, still.copy(), EVERY_FRAME)
    assert a.offset == 0 and a.align_err == 0.0


def test_offset_penalty_breaks_ties_between_equally_good_offsets():
    ref = moving_clip(20)
    # an exact match at +4 and, with a zero penalty, nothing else to prefer it over +4 itself
    costly = align(ref, delayed(ref, 4), AlignParams(offset_penalty=0.0))
    assert costly.offset == 4
    # a huge penalty forces the smallest offset among the refined candidates, though +4
    # matches exactly (the penalty acts in the refinement, on the coarse search's top k)
    forced = align(ref, delayed(ref, 4), AlignParams(offset_penalty=1e6))
    assert 4 in [o for o, _ in forced.candidates]
    assert forced.offset == min((o for o, _ in forced.candidates), key=abs) != 4
    assert forced.align_err > 0


def test_dtw_pairs_a_slowed_clip_monotonically():
    ref = moving_clip(24, seed=2)
    slow = ref[np.repeat(np.arange(12), 2)]  # first half at half speed
    a = align(ref, slow, AlignParams(dtw=True))
    assert a.method == "dtw"
    assert np.all(np.diff(a.ref_idx) >= 0) and np.all(np.diff(a.gen_idx) >= 0)
    assert (a.ref_idx[0], a.gen_idx[0]) == (0, 0)
    # every generated frame 2j (and 2j+1) shows reference frame j
    for r, g in a.pairs():
        if g < 22:
            assert r == g // 2 or np.array_equal(ref[r], slow[g])


def test_gray_features_are_block_means():
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, size=(2, 64, 48, 3), dtype=np.uint8)
    f = gray_features(frames, 16).reshape(2, 16, 16)
    gray = frames.astype(np.float64) @ np.array([0.299, 0.587, 0.114]) / 255.0
    expect = gray[:, :4, :3].mean(axis=(1, 2))  # top-left block: 64/16 rows × 48/16 columns
    assert np.allclose(f[:, 0, 0], expect, atol=1e-5)


def test_unaligned_pairs_every_frame_with_itself():
    a = unaligned(17, 17)
    assert a.pairs() == [(k, k) for k in range(17)] and a.offset == 0


# ----------------------------------------------------------------------------- scoring


def scene_for(n: int, size: int = 96, fps: float = 5.0) -> Scene:
    return Scene(scene_id="s0", dim="2d", clip=ClipInfo(fps=fps, n_frames=n, width=size,
                                                        height=size), video_path=Path("none.mp4"))


class ConstText(Metric):
    name = "const_text"
    direction = LOWER
    kind = SCENE
    family = "text"

    def compute(self, inp: MetricInput) -> float:
        return float(len(inp.analysis or ""))


def test_columns_follow_the_protocol():
    metrics = [PSNR(), ConstText()]
    full = [c for c, _ in score_columns(metrics, ScoringProtocol())]
    assert full == ["psnr", "psnr.aligned", "paper.psnr", "const_text", "align.offset",
                    "align.err", "paper.align.offset", "paper.align.err"]
    visphy_only = [c for c, _ in score_columns(metrics, ScoringProtocol(paper=False))]
    assert visphy_only == ["psnr", "psnr.aligned", "const_text", "align.offset", "align.err"]
    plain = [c for c, _ in score_columns(metrics, ScoringProtocol(aligned=False, paper=False))]
    assert plain == ["psnr", "const_text"]
    assert [c for c, _ in score_columns([ConstText()])] == ["const_text"]


def test_a_late_clip_scores_low_unaligned_and_exact_aligned(tmp_path):
    n, k = 30, 3
    ref = moving_clip(n, seed=5)
    gen = delayed(ref, k)
    scores, unavailable = score_scene(scene_for(n), ref, gen, [PSNR(), SSIM(), ConstText()],
                                      "abc", None, Cache(tmp_path / "c"))
    assert unavailable == {}
    assert scores["align.offset"] == k and scores["align.err"] == pytest.approx(0, abs=1e-9)
    unaligned_mean = np.mean([psnr_frame(a, b) for a, b in zip(ref, gen)])
    aligned_mean = np.mean([psnr_frame(ref[r], gen[r + k]) for r in range(n - k)])
    assert scores["psnr"] == pytest.approx(unaligned_mean)
    assert scores["psnr.aligned"] == pytest.approx(aligned_mean) == pytest.approx(100.0)
    assert scores["psnr"] < 40 < scores["psnr.aligned"]
    # the paper view: upstream's pairing (small squares on white: the raw cost of offset 0 is
    # below the penalty of +1 sampled frame, so upstream keeps 0, then warps by DTW)
    paper = align(ref, gen, PAPER)
    assert scores["paper.align.offset"] == paper.offset == 0
    assert scores["paper.psnr"] == pytest.approx(
        np.mean([paper_protocol.psnr(ref[r], gen[g]) for r, g in paper.pairs()]))
    assert scores["const_text"] == 3.0
    assert scores["ssim.aligned"] == pytest.approx(1.0) and scores["ssim"] < 0.99


def test_scores_are_cached_per_pairing(tmp_path):
    ref = moving_clip(17)
    cache = Cache(tmp_path / "c")
    first, _ = score_scene(scene_for(17), ref, delayed(ref, 2), [PSNR()], None, None, cache)
    again, _ = score_scene(scene_for(17), ref, delayed(ref, 2), [PSNR()], None, None, cache)
    assert first == again
    assert cache.stats()["score"]["hits"] == 3


class Missing(PSNR):
    name = "needs_weights"
    weights = "a network"

    def unavailable_reason(self):
        return "weights not found: put them in $VISPHY_WEIGHTS/x"


def test_an_unavailable_metric_has_no_number_in_any_pairing(tmp_path):
    ref = moving_clip(17)
    scores, unavailable = score_scene(scene_for(17), ref, ref, [Missing()], None, None,
                                      Cache(tmp_path / "c"))
    for col in ("needs_weights", "needs_weights.aligned", "paper.needs_weights"):
        assert scores[col] is None and "weights not found" in unavailable[col]


def test_protocol_from_config_and_its_checks():
    (cfg,) = check_overrides(["metrics.protocol=[visphy]", "metrics.aligned=false"])
    p = ScoringProtocol.from_cfg(cfg.metrics)
    assert p.views() == [""]
    (cfg,) = check_overrides(["metrics.protocol=[paper]", "metrics.paper.sample_every=2"])
    p = ScoringProtocol.from_cfg(cfg.metrics)
    assert p.views() == ["paper"] and p.paper_params.sample_every == 2
    (cfg,) = check_overrides([])
    assert ScoringProtocol.from_cfg(cfg.metrics).views() == ["", "aligned", "paper"]
    with pytest.raises(ConfigError, match="papr is not a scoring protocol"):
        check_overrides(["metrics.protocol=[papr]"])
    with pytest.raises(ConfigError, match="names no protocol"):
        check_overrides(["metrics.protocol=[]"])


def test_the_metrics_command_lists_what_each_metric_declares():
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "visphy_core", "metrics"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows = {line.split("│")[1].strip(): line for line in proc.stdout.splitlines()
            if line.startswith("│")}
    assert {"psnr", "ssim"} <= set(rows)
    assert "↑" in rows["psnr"] and "pairs" in rows["psnr"] and "available" in rows["psnr"]
