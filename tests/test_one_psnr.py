"""One per-frame PSNR (`visphy_core.api.psnr.psnr`): the ``psnr`` metric, the ``paper``
protocol (with upstream's perfect-match rule) and the report's per-frame curve give the same
value for the same pair of frames."""

from __future__ import annotations

import numpy as np

from visphy_core.api.psnr import PAPER_PERFECT_MSE, PSNR_CAP_DB, psnr
from visphy_core.infra.video import decode_video, encode_video
from visphy_core.report.frame_data import compute
from visphy_core.scoring import paper_protocol
from visphy_plugins.metrics.pixel import PSNR


def _reference_psnr(a: np.ndarray, b: np.ndarray, perfect_mse: float) -> float:
    """The textbook formula in float64, for comparison."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return PSNR_CAP_DB if mse <= perfect_mse else float(10.0 * np.log10(255.0**2 / mse))


def test_8_bit_frames_give_the_float64_formula_bit_for_bit():
    rng = np.random.default_rng(7)
    for k in range(60):
        shape = (int(rng.integers(1, 200)), int(rng.integers(1, 200)), (3, 4)[k % 2])
        a = rng.integers(0, 256, shape, dtype=np.uint8)
        b = np.clip(a.astype(int) + rng.integers(-40 * (k % 3), 40 * (k % 3) + 1, shape), 0,
                    255).astype(np.uint8)
        for rule in (psnr.__defaults__[0], PAPER_PERFECT_MSE):
            assert psnr(a, b, rule) == _reference_psnr(a, b, rule)
            assert psnr(a[::2, 1:], b[::2, 1:], rule) == _reference_psnr(a[::2, 1:], b[::2, 1:],
                                                                        rule)


def test_a_perfect_match_is_the_cap_and_only_the_paper_rule_goes_above_it():
    a = np.random.default_rng(1).integers(0, 256, (512, 512, 3), dtype=np.uint8)
    near = a.copy()
    near[5, 5, 1] ^= 1                     # one channel of one pixel off by one: 107 dB
    assert psnr(a, a) == psnr(a, a, PAPER_PERFECT_MSE) == PSNR_CAP_DB
    assert psnr(a, near) == PSNR_CAP_DB    # visphy: never above the metric's range
    assert paper_protocol.psnr(a, near) == psnr(a, near, PAPER_PERFECT_MSE)
    assert paper_protocol.psnr(a, near) > 107.0   # upstream: only MSE <= 1e-10 is capped
    assert list(PSNR().pair_values(a[None], near[None])) == [psnr(a, near)]


def test_the_reports_curve_is_the_psnr_metrics_per_frame_values(tmp_path):
    rng = np.random.default_rng(3)
    truth = rng.integers(0, 256, (6, 48, 64, 3), dtype=np.uint8)
    generated = truth.copy()
    generated[1:] = np.clip(truth[1:].astype(int) + rng.integers(-30, 31, truth[1:].shape), 0,
                            255).astype(np.uint8)
    encode_video(truth, tmp_path / "truth.mp4", 5)
    encode_video(generated, tmp_path / "gen.mp4", 5)
    data = compute(tmp_path / "truth.mp4", tmp_path / "gen.mp4", None, None)
    ref, _ = decode_video(tmp_path / "truth.mp4")
    gen, _ = decode_video(tmp_path / "gen.mp4")
    assert data["psnr"] == list(PSNR().pair_values(ref, gen))
    assert data["still"] == list(PSNR().pair_values(ref, np.repeat(ref[:1], len(ref), 0)))
    assert data["still"][0] == PSNR_CAP_DB
