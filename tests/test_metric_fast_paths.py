"""The metrics' fast paths against the implementations they replaced (kept as references).

Each fast path of the default offline suite is compared with its reference on frames that look
like the benchmark's renders — a 2D scene (PHYRE's flat palette, anti-aliased bodies moving
between frames, codec-like blur and noise) and a 3D one (sky and floor gradients, Lambert-shaded
spheres with soft shadows) — at 512², the benchmark's size, and at an odd size. Tolerances
(absolute, on the metric's value):

=============  ==========  =========================================================  ========
metric         tolerance   fast path                                                  version
=============  ==========  =========================================================  ========
``ssim``       0 (bit)     Y/R/G/B planes and moments in reused work arrays            1
``fsim``       0 (bit)     per frame: OpenCV scaling/pooling, phase congruency one      1
                           orientation at a time in reused buffers
``vsi``        0 (bit)     per frame: look-up scalings, SDSP's constant maps once,      1
                           LMN pooled by OpenCV
``st_lpips``   0 (bit)     channels-last weights, one frame at a time                  1
``st_lpips``   1e-3        opt-in bfloat16 (``VISPHY_STLPIPS_BF16=1``; identity       1
 (bf16)                    ``…/bf16``): measured |Δ| ≤ 4.8e-4
=============  ==========  =========================================================  ========

Every test fails when the fast path drifts from its reference by more than the tolerance
(`test_the_comparisons_can_fail` checks that the comparison itself catches a small change).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from visphy_plugins.metrics import _torch as _T
from visphy_plugins.metrics import pixel

torch = pytest.importorskip("torch")
piq = pytest.importorskip("piq")

from visphy_plugins.metrics import fsim_vsi as FV  # noqa: E402
from visphy_plugins.metrics import lpips_dists as LD  # noqa: E402


# ----------------------------------------------------------------------------- frames
def _supersampled(draw, size: int, ss: int = 3) -> np.ndarray:
    """``draw(yy, xx)`` → float RGB at ``ss``× the size, area-averaged down (anti-aliasing)."""
    yy, xx = np.mgrid[:size * ss, :size * ss] / ss
    big = draw(yy, xx)
    return big.reshape(size, ss, size, ss, 3).mean((1, 3))


def _codec(img: np.ndarray, seed: int) -> np.ndarray:
    """Mild blur and noise, as an H.264 round trip leaves on flat renders."""
    import cv2

    out = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.6)
    out += np.random.default_rng(seed).normal(0, 1.5, out.shape).astype(np.float32)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def frames_2d(n: int, size: int = 512, seed: int = 0) -> np.ndarray:
    """A PHYRE-like 2D clip: white background, black floor and bar, a red ball falling and a
    green and a blue body, moving from frame to frame."""
    s = size / 512
    out = []
    for k in range(n):
        def draw(yy, xx, k=k):
            img = np.empty((*yy.shape, 3))
            img[:] = (255, 255, 255)
            img[yy > 470 * s] = (0, 0, 0)
            bar = (np.abs(yy - 300 * s) < 6 * s) & (xx > 60 * s) & (xx < 330 * s)
            img[bar] = (0, 0, 0)
            cy = (80 + 22 * k + 3 * seed) * s
            img[(xx - 200 * s) ** 2 + (yy - cy) ** 2 < (28 * s) ** 2] = (240, 70, 60)
            img[(np.abs(xx - (380 - 6 * k) * s) < 30 * s) & (np.abs(yy - 420 * s) < 50 * s)] \
                = (90, 200, 100)
            img[(xx - (120 + 9 * k) * s) ** 2 + (yy - 440 * s) ** 2 < (30 * s) ** 2] \
                = (60, 110, 230)
            return img
        out.append(_codec(_supersampled(draw, size), seed * 100 + k))
    return np.stack(out)


def frames_3d(n: int, size: int = 512, seed: int = 0) -> np.ndarray:
    """A three.js-like 3D clip: sky gradient, a lit floor, two shaded spheres with shadows."""
    yy, xx = np.mgrid[:size, :size] / size
    out = []
    for k in range(n):
        img = np.empty((size, size, 3))
        sky = yy < 0.55
        img[sky] = (np.array([150, 190, 235]) * (1 - 0.4 * yy[sky])[:, None])
        floor = ~sky
        img[floor] = (np.array([185, 202, 210]) * (0.6 + 0.5 * yy[floor])[:, None])
        for (cx, cy, r, rgb) in (((0.3 + 0.03 * k, 0.5 - 0.02 * k + 0.01 * seed, 0.12,
                                   (230, 60, 50))),
                                 ((0.7 - 0.02 * k, 0.62, 0.09, (60, 120, 230)))):
            shadow = ((xx - cx - 0.05) / (1.2 * r)) ** 2 + ((yy - 0.78) / (0.3 * r)) ** 2 < 1
            img[shadow & floor] *= 0.55
            d2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / r ** 2
            disk = d2 < 1
            nz = np.sqrt(np.clip(1 - d2, 0, 1))
            shade = 0.25 + 0.75 * np.clip(0.5 * nz + 0.5 * ((cx - xx) + (cy - yy)) / r * 0.7,
                                           0, 1)
            img[disk] = np.array(rgb) * shade[disk][:, None]
        out.append(_codec(img, 1000 + seed * 100 + k))
    return np.stack(out)


@pytest.fixture(scope="module")
def clips() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(reference, generated) pair batches: 2D and 3D at 512², a generated clip two frames
    late with a different seed, and repeated frames (as the scorer's pairings have)."""
    r2, g2 = frames_2d(6), frames_2d(8, seed=1)[2:]
    r3, g3 = frames_3d(5), frames_3d(7, seed=1)[2:]
    return {"2d": (r2[[0, 1, 2, 3, 4, 5, 1]], g2[[0, 1, 2, 3, 4, 5, 2]]),
            "3d": (r3[[0, 1, 2, 3, 4]], g3[[1, 0, 2, 4, 3]]),
            "odd 2d": (frames_2d(3, 203)[:, :, :177], frames_2d(3, 203, seed=2)[:, :, :177])}


@pytest.fixture(autouse=True)
def fresh_frame_cache():
    _T.clear_frame_cache()
    yield
    _T.clear_frame_cache()


def close(ours, reference, atol: float) -> bool:
    ours, reference = np.asarray(ours, np.float64), np.asarray(reference, np.float64)
    return ours.shape == reference.shape and bool(
        np.all(np.abs(ours - reference) <= atol) and np.isfinite(ours).all())


def test_the_comparisons_can_fail(clips):
    """The helpers catch a change of one unit in the last place (what a tolerance of 0 means)
    and a NaN."""
    ref, gen = clips["2d"]
    value = pixel.SSIM().pair_values(ref[:2], gen[:2])
    assert close(value, value, 0.0)
    assert not close(np.nextafter(value, 2.0), value, 0.0)
    assert not close(value + 2e-6, value, 1e-6)
    assert not close(np.full_like(value, np.nan), value, 1.0)


# ----------------------------------------------------------------------------- SSIM
@pytest.mark.parametrize("case", ["2d", "3d", "odd 2d"])
def test_ssim_moments_equal_the_reference_bit_for_bit(clips, case):
    for frame in clips[case][0][:3]:
        h, w = frame.shape[:2]
        ours = pixel._moments_into(frame, np.empty((4, 2, h, w), np.float32))
        theirs = pixel._reference_moments_into(frame, np.empty((4, 2, h, w), np.float32))
        assert np.array_equal(ours, theirs)
        planes = pixel._Planes((h, w))
        assert all(np.array_equal(p, c) for p, c in zip(planes.load(frame),
                                                          pixel._channels(frame)))


@pytest.mark.parametrize("case", ["2d", "3d", "odd 2d"])
def test_ssim_fast_path_equals_ssim_frame_bit_for_bit(clips, case, monkeypatch):
    """Both paths (moments kept in the per-frame cache, or computed pair by pair into reused
    arrays when a batch would not fit) give `ssim_frame`'s values, bit for bit."""
    ref, gen = clips[case]
    expected = [pixel.ssim_frame(a, b) for a, b in zip(ref, gen)]
    assert close(pixel.SSIM().pair_values(ref, gen), expected, 0.0)
    assert _T._frames_bytes > 0  # kept
    monkeypatch.setattr(_T, "FRAME_CACHE_BYTES", 1)
    _T.clear_frame_cache()
    assert close(pixel.SSIM().pair_values(ref, gen), expected, 0.0)
    assert _T._frames_bytes == 0  # pair by pair


# ----------------------------------------------------------------------------- FSIM
@pytest.mark.parametrize("case", ["2d", "3d", "odd 2d"])
def test_fsim_features_one_frame_at_a_time_equal_the_batch(clips, case):
    metric = FV.FSIM()
    frames = clips[case][0][:4]
    with torch.inference_mode():
        ours = metric.frame_features(frames)
        theirs = metric._reference_frame_features(frames)  # the previous path: the batch
    assert len(ours) == len(theirs) == len(frames)
    for fo, ft in zip(ours, theirs):
        assert all(torch.equal(a, b) for a, b in zip(fo, ft))


@pytest.mark.parametrize("size", [64, 131, 256])
def test_fsim_phase_congruency_fast_is_piqs_bit_for_bit(size):
    from piq.fsim import _phase_congruency

    d = FV._defaults(piq.fsim)
    frames = np.concatenate([frames_2d(2, size), frames_3d(2, size)])
    x = (torch.from_numpy(frames).permute(0, 3, 1, 2).float() * 1.0)[:, :1]
    with torch.inference_mode():
        bank = FV._fsim_filters(x, d)
        theirs = _phase_congruency(x, bank[0], d["scales"], d["orientations"], d["k"])
        ours = torch.cat([FV._phase_congruency_fast(x[i:i + 1], bank, d["scales"],
                                                    d["orientations"], d["k"])
                          for i in range(len(x))])
        assert torch.equal(ours, theirs)
        # a batch too
        assert torch.equal(FV._phase_congruency_fast(x, bank, d["scales"], d["orientations"],
                                                     d["k"]), theirs)


def test_lower_median_is_torchs():
    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 64, 65536):
        x = torch.from_numpy(rng.random((1, 4, 1, 1, n), dtype=np.float32) ** 2)
        x[0, 1, 0, 0, : n // 2] = 0.25  # ties
        assert torch.equal(FV._lower_median(x), torch.median(x, dim=-1, keepdim=True).values)
    x[0, 2, 0, 0, 0] = float("nan")  # torch's own rule where a value is not finite
    ours, theirs = FV._lower_median(x), torch.median(x, dim=-1, keepdim=True).values
    assert torch.equal(ours.nan_to_num(-1.0), theirs.nan_to_num(-1.0))


def test_fsim_input_is_torchs_bit_for_bit(clips):
    """The look-up table and OpenCV's 2×2 area resize give torch's ×255 and avg_pool2d."""
    t = torch
    for frame in (clips["2d"][0][0], clips["3d"][1][2], clips["odd 2d"][0][1],
                  np.random.default_rng(0).integers(0, 256, (517, 515, 3), np.uint8)):
        x = _T.to_tensor(frame[None]) / float(1.0) * 255
        x = t.nn.functional.avg_pool2d(x, max(1, round(min(x.shape[-2:]) / 256)))
        ours = FV._fsim_input(frame)
        assert ours.shape == x.shape and ours.stride() == x.stride()
        assert torch.equal(ours, x)
    assert FV._fsim_input(frame.astype(np.float32)) is None
    assert FV._fsim_input(np.zeros((900, 900, 3), np.uint8)) is None  # pooled by 4


@pytest.mark.parametrize("case", ["2d", "3d"])
def test_fsim_equals_piq(clips, case):
    ref, gen = clips[case]
    ours = FV.FSIM().pair_values(ref[:3], gen[:3])
    x = torch.from_numpy(ref[:3]).permute(0, 3, 1, 2).float() / 255
    y = torch.from_numpy(gen[:3]).permute(0, 3, 1, 2).float() / 255
    with torch.inference_mode():
        theirs = piq.fsim(x, y, data_range=1.0, reduction="none").double().numpy()
    assert close(ours, theirs, 1e-6)


# ----------------------------------------------------------------------------- VSI
#: VSI's fast path gives the reference's values bit for bit (its LMN maps too: VSI's
#: |s_c|^0.02 turns an ulp of LMN into up to 1.4e-5 of VSI on noise frames)
VSI_ATOL = 0.0


@pytest.mark.parametrize("case", ["2d", "3d", "odd 2d"])
def test_vsi_features_equal_the_reference(clips, case):
    """Every map bit for bit: saliency, L's gradient, M and N."""
    metric = FV.VSI()
    frames = clips[case][0][:3]
    with torch.inference_mode():
        ours = metric.frame_features(frames)
        theirs = metric._reference_frame_features(frames)
    for fo, ft in zip(ours, theirs):
        assert len(fo) == len(ft) == 4
        assert all(torch.equal(a, b) for a, b in zip(fo, ft))


@pytest.mark.parametrize("case", ["2d", "3d", "odd 2d", "noise"])
def test_vsi_equals_piq_and_the_reference(clips, case):
    if case == "noise":  # independent noise frames: VSI at its most sensitive (s_c near 0)
        rng = np.random.default_rng(6)
        ref, gen = (rng.integers(0, 256, (2, size, size, 3), np.uint8) for size in (192, 192))
    else:
        ref, gen = clips[case]
    metric = FV.VSI()
    ours = metric.pair_values(ref, gen)
    x = torch.from_numpy(np.ascontiguousarray(ref)).permute(0, 3, 1, 2).float() / 255
    y = torch.from_numpy(np.ascontiguousarray(gen)).permute(0, 3, 1, 2).float() / 255
    with torch.inference_mode(), _T.threads(1):  # (the metric's thread count)
        theirs = piq.vsi(x, y, data_range=1.0, reduction="none").double().numpy()
        before = []
        for a, b in zip(ref, gen):
            fa = metric._reference_frame_features(a[None])[0]
            fb = metric._reference_frame_features(b[None])[0]
            before.append(float(metric.combine(fa, fb)))
    assert close(ours, theirs, 1e-6)  # piq on the batch (its own float32 rounding)
    assert close(ours, before, VSI_ATOL)


def test_vsi_sdsp_is_piqs_bit_for_bit(clips):
    from piq.vsi import sdsp

    d = FV._defaults(piq.vsi)
    for frames in (clips["2d"][0][:2], clips["odd 2d"][1][:2]):
        x = _T.to_tensor(frames) * 255. / float(1.0)
        with torch.inference_mode():
            theirs = sdsp(x, data_range=255, omega_0=d["omega_0"], sigma_f=d["sigma_f"],
                          sigma_d=d["sigma_d"], sigma_c=d["sigma_c"])
            ours = FV._sdsp(x / float(255) * 255, d)
        assert torch.equal(ours, theirs)


# ----------------------------------------------------------------------------- ST-LPIPS
def _stlpips_reference(metric, ref: np.ndarray, gen: np.ndarray) -> np.ndarray:
    """The previous computation: the net's weights in torch's default layout, the features of
    each side's batch (chunks of four frames) at once."""
    from stlpips_pytorch import utils

    model = copy.deepcopy(metric.model()).to(memory_format=torch.contiguous_format)
    assert model.net.slice1[0].weight.is_contiguous()
    out = []
    with torch.inference_mode():
        for s in range(0, len(ref), LD.CHUNK):
            fx = LD._lpips_features(model, metric._tensor(ref[s:s + LD.CHUNK]),
                                    utils.normalize_tensor)
            fy = LD._lpips_features(model, metric._tensor(gen[s:s + LD.CHUNK]),
                                    utils.normalize_tensor)
            out += [float(LD._lpips_combine(model, a, b)) for a, b in zip(fx, fy)]
    return np.array(out)


@pytest.mark.parametrize("case", ["2d", "3d", "odd 2d"])
def test_st_lpips_fast_path_equals_the_reference(clips, case):
    metric = LD.STLPIPS()
    assert metric.unavailable_reason() is None
    assert metric.model().net.slice1[0].weight.is_contiguous(
        memory_format=torch.channels_last)
    ref, gen = clips[case]
    ours = metric.pair_values(ref, gen)
    assert close(ours, _stlpips_reference(metric, ref, gen), 0.0)
    with torch.inference_mode():  # and the package's own forward, pair by pair
        direct = [float(metric.forward(metric.model(), metric._tensor(a[None]),
                                       metric._tensor(b[None])).flatten()[0])
                  for a, b in zip(ref, gen)]
    assert close(ours, direct, 1e-6)


#: bfloat16 ST-LPIPS (opt-in, ``VISPHY_STLPIPS_BF16=1``): measured on 15 scenes of the
#: benchmark's sub split (12 2D, 3 3D; 24 pairs each), |Δ| ≤ 4.8e-4 on values up to 0.24
#: (≤ 0.7 % of values above 1e-3)
STLPIPS_BF16_ATOL = 1e-3


def test_st_lpips_bf16_is_opt_in_within_its_tolerance(clips, monkeypatch):
    metric = LD.STLPIPS()
    monkeypatch.delenv(LD.STLPIPS_BF16_ENV, raising=False)
    assert metric.precision() == "fp32"
    fp32_identity = metric.identity()
    ref, gen = clips["2d"]
    ref, gen = ref[[0, 1, 2, 6]], gen[[0, 1, 2, 6]]  # a repeat on each side; bf16 is slow here
    fp32 = metric.pair_values(ref, gen)
    monkeypatch.setenv(LD.STLPIPS_BF16_ENV, "1")
    assert metric.precision() == "bf16"
    assert metric.identity() != fp32_identity and "/bf16" in metric.identity()
    hits = _T.frame_cache_stats["hits"]
    bf16 = metric.pair_values(ref, gen)  # never served the fp32 features of the cache
    assert _T.frame_cache_stats["hits"] - hits == 2  # its own repeats only (frame 1, 2)
    assert close(bf16, fp32, STLPIPS_BF16_ATOL)
    assert not np.array_equal(bf16, fp32)  # it did run in bfloat16
    assert close(metric.pair_values(ref, gen), bf16, 0.0)  # repeatable
    monkeypatch.setenv(LD.STLPIPS_BF16_ENV, "0")
    assert metric.identity() == fp32_identity
    monkeypatch.setenv(LD.STLPIPS_BF16_ENV, "maybe")
    with pytest.raises(ValueError, match=LD.STLPIPS_BF16_ENV):
        metric.precision()


@pytest.mark.parametrize("name", ["fsim", "vsi"])
def test_fsim_vsi_run_on_one_thread_whatever_the_process_count(clips, name):
    """Per frame and per pair the piq metrics run on one torch thread (too small to share):
    the values are the same at any process thread count, and the count is restored."""
    metric = {"fsim": FV.FSIM, "vsi": FV.VSI}[name]()
    ref, gen = clips["3d"]
    _T.torch()  # (its first call sets the process's count)
    before = torch.get_num_threads()
    values = {}
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            _T.clear_frame_cache()
            values[n] = metric.pair_values(ref[:3], gen[:3])
            assert torch.get_num_threads() == n
    finally:
        torch.set_num_threads(before)
    assert close(values[2], values[1], 0.0)
