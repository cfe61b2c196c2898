"""Cache, video and pixel-metric behaviour."""

from __future__ import annotations

import numpy as np
import pytest

from visphy_core.infra.cache import Cache, content_key
from visphy_core.infra.video import (
    ClipInfo,
    decode_video,
    encode_video,
    frame_digest,
    normalise_clip,
)
from visphy_plugins.metrics.pixel import psnr_frame, ssim_frame


def test_cache_entries_are_atomic_and_counted(tmp_path):
    cache = Cache(tmp_path)
    key = content_key("render", {"a": 1})
    assert cache.get("render", key) is None
    entry = cache.put("render", key, {"meta.json": "{}", "video.mp4": b"\x00\x01"})
    assert (entry / "video.mp4").read_bytes() == b"\x00\x01"
    assert cache.get("render", key) == entry
    assert cache.stats() == {"render": {"hits": 1, "misses": 1}}
    assert content_key({"a": 1, "b": 2}) == content_key({"b": 2, "a": 1})
    assert not list(entry.parent.glob(".*"))  # no temp dirs left behind


def _clip(n=5, size=32):
    rng = np.random.default_rng(0)
    return rng.integers(0, 255, (n, size, size, 3), dtype=np.uint8)


def test_encoding_is_byte_identical_for_identical_frames(tmp_path):
    frames = _clip()
    a = encode_video(frames, tmp_path / "a.mp4", 5).read_bytes()
    b = encode_video(frames, tmp_path / "b.mp4", 5).read_bytes()
    assert a == b
    decoded, info = decode_video(tmp_path / "a.mp4")
    assert info == ClipInfo(fps=5.0, n_frames=5, width=32, height=32)


def test_missing_and_corrupt_videos_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.mp4"):
        decode_video(tmp_path / "nope.mp4")
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video")
    with pytest.raises(ValueError, match="bad.mp4"):
        decode_video(bad)


def test_normalise_pairs_frames_by_time_not_index():
    frames = np.stack([np.full((4, 4, 3), i, np.uint8) for i in range(30)])  # 15 fps, 2 s
    out = normalise_clip(frames, 15.0, ClipInfo(fps=5, n_frames=12, width=8, height=8))
    assert out.shape == (12, 8, 8, 3)
    # frame k at k/5 s is source frame 3k; past the source's end the last frame is held
    assert [int(f[4, 4, 0]) for f in out] == [0, 3, 6, 9, 12, 15, 18, 21, 24, 27, 29, 29]


def test_psnr_and_ssim_behave():
    a = _clip(1, 64)[0]
    assert psnr_frame(a, a) == 100.0
    assert ssim_frame(a, a) == pytest.approx(1.0)
    noisy = np.clip(a.astype(int) + np.random.default_rng(1).normal(0, 5, a.shape), 0, 255)
    noisy = noisy.astype(np.uint8)
    mse = np.mean((a.astype(float) - noisy.astype(float)) ** 2)
    assert psnr_frame(a, noisy) == pytest.approx(10 * np.log10(255**2 / mse))
    worse = np.clip(a.astype(int) + np.random.default_rng(1).normal(0, 40, a.shape), 0, 255)
    assert ssim_frame(a, worse.astype(np.uint8)) < ssim_frame(a, noisy) < 1.0


def test_frame_digest_depends_on_content_and_shape():
    a = np.zeros((4, 4, 3), np.uint8)
    assert frame_digest(a) != frame_digest(np.zeros((2, 8, 3), np.uint8))
    b = a.copy()
    b[0, 0, 0] = 1
    assert frame_digest(a) != frame_digest(b)


def test_ssim_matches_scikit_image_reference():
    """Calibration against scikit-image's Gaussian-window SSIM (Wang et al. 2004 settings)."""
    skimage_metrics = pytest.importorskip("skimage.metrics")
    from visphy_plugins.metrics.pixel import ssim_channel

    rng = np.random.default_rng(3)
    x = rng.integers(0, 255, (96, 96)).astype(np.float64)
    y = np.clip(x + rng.normal(0, 20, x.shape), 0, 255)
    ref = skimage_metrics.structural_similarity(x, y, gaussian_weights=True, sigma=1.5,
                                                use_sample_covariance=False, data_range=255)
    assert ssim_channel(x, y) == pytest.approx(ref, abs=1e-6)


def test_a_disabled_cache_recomputes_but_still_stores(tmp_path):
    cache = Cache(tmp_path, enabled=False)
    key = content_key("x")
    entry = cache.put("score", key, {"value.json": "1"})
    assert (entry / "value.json").read_text() == "1"
    assert cache.get("score", key) is None
    assert cache.stats() == {"score": {"hits": 0, "misses": 1}}


def test_normalise_command_matches_a_foreign_video_to_the_reference(tmp_path):
    """A 30 fps 320×240 clip becomes the reference's 5 fps, 17 frames, 64×64 (padded)."""
    import subprocess
    import sys

    ref = encode_video(np.full((17, 64, 64, 3), 255, np.uint8), tmp_path / "ref.mp4", 5)
    foreign = np.zeros((60, 240, 320, 3), np.uint8)
    foreign[:, :, :, 0] = np.arange(60)[:, None, None] * 4  # red level encodes the frame index
    encode_video(foreign, tmp_path / "foreign.mp4", 30)
    out = tmp_path / "out.mp4"
    subprocess.run([sys.executable, "-m", "visphy_core", "normalise", str(tmp_path / "foreign.mp4"),
                    "--like", str(ref), "-o", str(out)], check=True, capture_output=True)
    frames, info = decode_video(out)
    assert info == ClipInfo(fps=5.0, n_frames=17, width=64, height=64)
    # frame k shows the foreign frame at k/5 s = index 6k (held at 59 after 2 s); letterboxed
    reds = [int(f[32, 32, 0]) for f in frames]
    expected = [min(6 * k, 59) * 4 for k in range(17)]
    assert all(abs(r - e) <= 6 for r, e in zip(reds, expected)), (reds, expected)
    assert frames[0][2, 32].min() > 240  # white padding above the 4:3 picture


# --------------------------------------------------------------------------- files, png, settings
def test_atomic_write_replaces_whole_files_and_leaves_no_temporaries(tmp_path):
    from visphy_core.infra.files import atomic_write

    path = tmp_path / "a" / "b.txt"
    atomic_write(path, "first ✓")
    atomic_write(path, b"second")
    assert path.read_bytes() == b"second"
    assert sorted(p.name for p in path.parent.iterdir()) == ["b.txt"]
    with pytest.raises(TypeError):
        atomic_write(path, 3)  # type: ignore[arg-type]
    assert path.read_bytes() == b"second" and len(list(path.parent.iterdir())) == 1


def test_png_round_trip_and_transparency_over_a_background():
    from visphy_core.infra.png import decode_png, png_bytes

    rgb = np.random.default_rng(0).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    assert np.array_equal(decode_png(png_bytes(rgb)), rgb)
    assert png_bytes(rgb) == png_bytes(rgb.copy())
    rgba = np.zeros((2, 2, 4), dtype=np.uint8)
    rgba[0, 0] = (10, 20, 30, 255)                     # opaque; the rest fully transparent
    over_white = decode_png(png_bytes(rgba), background=(255, 255, 255))
    assert over_white[0, 0].tolist() == [10, 20, 30] and over_white[1, 1].tolist() == [255] * 3
    assert decode_png(png_bytes(rgba))[1, 1].tolist() == [0, 0, 0]  # alpha dropped


def test_cfg_get_reads_any_node_and_falls_back_on_absent_or_none():
    from omegaconf import OmegaConf

    from visphy_core.api.settings import cfg_get

    strict = OmegaConf.structured({"a": 1, "b": None})
    OmegaConf.set_struct(strict, True)
    assert cfg_get(strict, "a", 5) == 1 and cfg_get(strict, "b", 5) == 5
    assert cfg_get(strict, "unknown", 7) == 7          # struct configs raise on unknown keys
    assert cfg_get({"a": 0}, "a", 9) == 0              # a falsy value is a value
    assert cfg_get(None, "a", 3) == 3

    class Obj:
        a = 2

    assert cfg_get(Obj(), "a") == 2 and cfg_get(Obj(), "z", "d") == "d"


def test_a_sequence_metric_is_computed_once_for_pairings_with_the_same_pairs(tmp_path,
                                                                             mini_scenes):
    """The aligned pairing at offset 0 has the unaligned pairing's pairs: one computation, the
    same value in both columns; a clip whose best offset is not 0 is computed per pairing."""
    from visphy_core.api.metrics import SEQUENCE, Metric
    from visphy_core.scoring.score import ScoringProtocol, score_scene

    class Counting(Metric):
        name, kind = "counting", SEQUENCE

        def __init__(self):
            self.calls = []

        def compute_sequence(self, inp, alignment):
            self.calls.append(alignment.pairs())
            return float(len(self.calls))

    scene = mini_scenes[0]
    reference = scene.reference_frames()
    protocol = ScoringProtocol(unaligned=True, aligned=True, paper=False)
    metric = Counting()
    scores, _ = score_scene(scene, reference, reference.copy(), [metric], None, None,
                            Cache(tmp_path / "a"), protocol=protocol)
    assert len(metric.calls) == 1 and scores["counting"] == scores["counting.aligned"] == 1.0
    late = np.concatenate([reference[:1]] * 3 + [reference[:-3]])  # three frames late
    metric = Counting()
    scores, _ = score_scene(scene, reference, late, [metric], None, None,
                            Cache(tmp_path / "b"), protocol=protocol)
    assert len(metric.calls) == 2 and metric.calls[0] != metric.calls[1]
    assert scores["counting"] == 1.0 and scores["counting.aligned"] == 2.0


def test_work_order_spreads_scenes_too_large_to_score_side_by_side(monkeypatch):
    """3D clips (75 frames of 512²) at the end of a split are spread among the 2D ones, each
    group in its own order; a list of one size, or no scoring limit, keeps its order."""
    from types import SimpleNamespace

    from visphy_core.execute.scheduler import SCORE_PIXELS_ENV, work_order

    def scene(name: str, frames: int):
        return SimpleNamespace(name=name, clip=SimpleNamespace(n_frames=frames, width=512,
                                                               height=512))

    small = [scene(f"2d{i}", 17) for i in range(10)]
    large = [scene(f"3d{i}", 75) for i in range(3)]
    order = [s.name for s in work_order(small + large)]
    assert order == ["2d0", "2d1", "3d0", "2d2", "2d3", "2d4", "3d1", "2d5", "2d6", "2d7",
                     "2d8", "3d2", "2d9"]
    assert sorted(order) == sorted(s.name for s in small + large)
    assert work_order(small) == small and work_order(large) == large
    monkeypatch.setenv(SCORE_PIXELS_ENV, "0")   # no scoring limit: nothing to spread
    assert work_order(small + large) == small + large
