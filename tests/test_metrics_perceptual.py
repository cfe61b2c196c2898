"""Perceptual metrics (`visphy_plugins.metrics.ms_ssim`, `.fsim_vsi`, `.lpips_dists`) and the
pixel metrics' calibration.

* PSNR/SSIM (`visphy_plugins.metrics.pixel`) equal scikit-image's;
* ``ms_ssim``/``fsim``/``vsi`` equal direct piq calls on the full-size frames (FSIM/VSI to 1e-6,
  MS-SSIM, re-implemented with separable OpenCV filters, to 1e-4 on rendered and random frames
  of several sizes);
* the per-frame paths (each frame's share computed once per distinct frame and cached across
  calls: SSIM, FSIM, VSI, ST-LPIPS, LPIPS) equal the per-pair computation, whether frames repeat
  in a batch, across calls or not at all;
* ``st_lpips`` is available from the stlpips-pytorch package alone, every parameter loaded, and
  reproduces the package's own API (its README's published value, 0.7778 for the LPIPS repo's
  ``imgs/ex_p0.png`` vs ``imgs/ex_ref.png``, needs images the package does not ship and that cannot
  be fetched here: the reference values are the package's own outputs on the frames below);
* ``lpips`` and ``dists`` run their real architectures from weight files in a weight directory
  (random initialisations saved by the tests, their SHA-256 standing in for the published ones
  for the test: the real checkpoints are not on this machine), equal the upstream
  implementations (lpips package, piq.DISTS) given the same weights, and are unavailable (None
  in every column, with the reason) without them;
* every weight file is checked against its published SHA-256: a file with the right name and
  other content (or with no published SHA-256) is never used, the packaged ST-LPIPS and LPIPS
  files pass;
* every metric moves the right way with growing noise and blur.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
piq = pytest.importorskip("piq")
pytest.importorskip("torchvision")

from visphy_core.api import weights  # noqa: E402
from visphy_core.api.metrics import HIGHER, LOWER, PAIRS  # noqa: E402
from visphy_core.api.scene import ClipInfo, Scene  # noqa: E402
from visphy_core.infra.cache import Cache  # noqa: E402
from visphy_core.scoring.score import score_scene  # noqa: E402
from visphy_plugins.metrics import _torch as _T  # noqa: E402
from visphy_plugins.metrics import fsim_vsi as FV  # noqa: E402
from visphy_plugins.metrics import lpips_dists as LD  # noqa: E402
from visphy_plugins.metrics import ms_ssim as MS  # noqa: E402
from visphy_plugins.metrics.pixel import PSNR, SSIM, psnr_frame, ssim_frame  # noqa: E402


# ----------------------------------------------------------------------------- frames
def structured(n: int, size: int, seed: int = 0) -> np.ndarray:
    """Frames with edges, gradients, colour and a moving disk (what renders look like)."""
    yy, xx = np.mgrid[:size, :size]
    out = np.empty((n, size, size, 3), np.uint8)
    for i in range(n):
        img = np.empty((size, size, 3), np.float64)
        img[..., 0] = 40 + 150 * xx / size
        img[..., 1] = 60 + 120 * yy / size
        img[..., 2] = 200 - 100 * (xx + yy) / (2 * size)
        img[((xx // max(1, size // 8)) + (yy // max(1, size // 8))) % 2 == 0] *= 0.8
        cx, cy, r = size * (0.3 + 0.05 * i), size * (0.45 + 0.02 * seed), size * 0.15
        img[(xx - cx) ** 2 + (yy - cy) ** 2 < r * r] = (230, 40, 30)
        img[int(size * 0.8):int(size * 0.85), int(size * 0.1):int(size * 0.9)] = (30, 30, 30)
        out[i] = np.clip(img, 0, 255).astype(np.uint8)
    return out


def random_frames(n: int, size: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, size, size, 3), dtype=np.uint8)


def noisy(frames: np.ndarray, sigma: float, seed: int = 1) -> np.ndarray:
    noise = np.random.default_rng(seed).normal(0, sigma, frames.shape)
    return np.clip(frames + noise, 0, 255).round().astype(np.uint8)


def blurred(frames: np.ndarray, sigma: float) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    return np.stack([np.clip(gaussian_filter(f.astype(np.float64), (sigma, sigma, 0)), 0, 255)
                     .round().astype(np.uint8) for f in frames])


def to01(frames: np.ndarray):
    return torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float() / 255.0


# ----------------------------------------------------------------------------- weight dirs
@pytest.fixture(autouse=True)
def fresh_frame_cache():
    """Every test starts with an empty per-frame cache (what a test computes is its own)."""
    _T.clear_frame_cache()
    yield
    _T.clear_frame_cache()


@pytest.fixture(autouse=True)
def weight_dir(tmp_path, monkeypatch):
    """An empty configured weight directory as the only place weights are searched (the
    torch-hub cache pointed at an empty directory too), for every test: weights this machine
    may hold elsewhere never leak in; reset afterwards."""
    d = tmp_path / "weights"
    d.mkdir()
    monkeypatch.delenv("VISPHY_WEIGHTS", raising=False)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    # the published SHA-256 table, for this test: the random checkpoints below add themselves
    monkeypatch.setattr(weights, "PUBLISHED", dict(weights.PUBLISHED))
    weights.configure(d)
    yield d
    weights.configure(None)


def publish(path: Path, key: str | None = None) -> None:
    """Let a random-init stand-in pass as the published file (this test only: `weight_dir`
    restores the table)."""
    weights.PUBLISHED[key or path.name] = weights.Published(weights.sha256(path), "test")


def save_alexnet(path: Path, seed: int, published: bool = True) -> dict:
    """A random-init torchvision AlexNet state dict (the ``features`` part the metric loads; the
    classifier is left out to keep the file small)."""
    from torchvision.models.alexnet import AlexNet

    torch.manual_seed(seed)
    sd = {f"features.{k}": v for k, v in AlexNet().features.state_dict().items()}
    torch.save(sd, path)
    if published:
        publish(path)
    return sd


def save_vgg16_features(path: Path, seed: int) -> dict:
    from torchvision.models.vgg import cfgs, make_layers

    torch.manual_seed(seed)
    sd = {f"features.{k}": v for k, v in make_layers(cfgs["D"]).state_dict().items()}
    torch.save(sd, path)
    publish(path)
    return sd


def save_dists_ab(path: Path, seed: int, published: bool = True) -> dict:
    g = torch.Generator().manual_seed(seed)
    ab = {"alpha": torch.rand(1, 1475, 1, 1, generator=g) * 0.01 + 0.1,
          "beta": torch.rand(1, 1475, 1, 1, generator=g) * 0.01 + 0.1}
    torch.save(ab, path)
    if published:
        publish(path)
    return ab


def scene_for(n: int, size: int) -> Scene:
    return Scene(scene_id="s0", dim="2d", clip=ClipInfo(fps=5.0, n_frames=n, width=size,
                                                        height=size), video_path=Path("none.mp4"))


# ----------------------------------------------------------------------------- pixel metrics
def test_psnr_matches_skimage():
    from skimage.metrics import peak_signal_noise_ratio

    ref = structured(3, 64)
    gen = noisy(ref, 12.0)
    ours = PSNR().pair_values(ref, gen)
    theirs = [peak_signal_noise_ratio(a, b, data_range=255) for a, b in zip(ref, gen)]
    assert np.allclose(ours, theirs, rtol=0, atol=1e-4)
    assert psnr_frame(ref[0], ref[0]) == 100.0  # identical: the cap (skimage: inf)


@pytest.mark.parametrize("make", ["structured", "random"])
def test_ssim_matches_skimage_per_channel(make):
    """pixel.py's SSIM is skimage's (Gaussian window σ 1.5, 11 taps, population covariance,
    L 255, K1 0.01, K2 0.03, borders of radius 5 cropped) averaged over Y, R, G, B."""
    from skimage.metrics import structural_similarity

    ref = structured(2, 64) if make == "structured" else random_frames(2, 64, 3)
    gen = noisy(blurred(ref, 1.0), 8.0)

    def channels(f):
        f = f.astype(np.float64)
        return [0.299 * f[..., 0] + 0.587 * f[..., 1] + 0.114 * f[..., 2],
                f[..., 0], f[..., 1], f[..., 2]]

    for a, b in zip(ref, gen):
        per = [structural_similarity(x, y, gaussian_weights=True, sigma=1.5,
                                     use_sample_covariance=False, data_range=255)
               for x, y in zip(channels(a), channels(b))]
        # skimage's full map cropped by the same radius gives the same mean
        maps = [structural_similarity(x, y, gaussian_weights=True, sigma=1.5,
                                      use_sample_covariance=False, data_range=255,
                                      full=True)[1][5:-5, 5:-5].mean()
                for x, y in zip(channels(a), channels(b))]
        assert ssim_frame(a, b) == pytest.approx(np.mean(per), abs=1e-4)
        assert np.mean(per) == pytest.approx(np.mean(maps), abs=1e-12)
    assert np.allclose(SSIM().pair_values(ref, gen),
                       [ssim_frame(a, b) for a, b in zip(ref, gen)])


# ----------------------------------------------------------------------------- piq metrics
PIQ_CALLS = {
    "ms_ssim": lambda x, y: piq.multi_scale_ssim(x, y, data_range=1.0, reduction="none"),
    "fsim": lambda x, y: piq.fsim(x, y, data_range=1.0, reduction="none"),
    "vsi": lambda x, y: piq.vsi(x, y, data_range=1.0, reduction="none"),
}
PIQ_METRICS = {"ms_ssim": MS.MSSSIM, "fsim": FV.FSIM, "vsi": FV.VSI}
#: MS-SSIM is computed with OpenCV (float32 filters, float64 means): within a few 1e-6 of piq's
#: float32 value; FSIM and VSI call piq's own functions per frame and per pair
PIQ_ATOL = {"ms_ssim": 1e-4, "fsim": 1e-6, "vsi": 1e-6}


@pytest.mark.parametrize("name", list(PIQ_METRICS))
def test_piq_metrics_equal_direct_piq_calls(name):
    """Five pairs (more than one chunk) at 192² (MS-SSIM needs ≥ 161 px) and 520² (FSIM/VSI
    pool by 2 inside piq there): the values are piq's on the full-size frames."""
    metric = PIQ_METRICS[name]()
    assert metric.unavailable_reason() is None
    assert (metric.kind, metric.direction, metric.score_range) == (PAIRS, HIGHER, (0.0, 1.0))
    ref = np.concatenate([structured(3, 192), random_frames(2, 192, 5)])
    gen = np.concatenate([noisy(structured(3, 192, seed=1), 10.0), random_frames(2, 192, 6)])
    ours = metric.pair_values(ref, gen)
    with torch.inference_mode():
        theirs = PIQ_CALLS[name](to01(ref), to01(gen)).double().numpy()
    assert ours.shape == (5,)
    assert np.allclose(ours, theirs, rtol=0, atol=PIQ_ATOL[name])
    assert np.allclose(metric.pair_values(ref[:2], ref[:2]), 1.0, atol=1e-6)
    big_r, big_g = structured(1, 520), noisy(structured(1, 520, seed=2), 10.0)
    with torch.inference_mode():
        direct = PIQ_CALLS[name](to01(big_r), to01(big_g)).double().numpy()
    assert np.allclose(metric.pair_values(big_r, big_g), direct, rtol=0, atol=PIQ_ATOL[name])


def _rendered_pairs(mini_scenes) -> tuple[np.ndarray, np.ndarray]:
    """Rendered 512² frames of the mini build, each against the frame two steps later."""
    ref, gen = [], []
    for scene in mini_scenes[:2]:
        frames = scene.reference_frames()
        ref += [frames[0], frames[len(frames) // 2]]
        gen += [frames[2], frames[len(frames) // 2 + 2]]
    return np.stack(ref), np.stack(gen)


def test_ms_ssim_equals_piq_on_rendered_and_random_frames(mini_scenes):
    """``ms_ssim`` is `piq.multi_scale_ssim(x, y, data_range=1.0, reduction='none')` to 1e-4 on
    rendered frames at 512², 256² (2×2 means) and odd crops, and on random and noisy images at
    several sizes down to 161 (its float32 rounding, not piq's: it is closer to piq's float64
    value than piq's float32 value is)."""
    ref, gen = _rendered_pairs(mini_scenes)
    half = lambda f: f.reshape(len(f), 256, 2, 256, 2, 3).mean((2, 4)).round().astype(np.uint8)  # noqa: E731
    cases = {"rendered 512": (ref, gen), "rendered 256": (half(ref), half(gen)),
             "rendered 161x203": (ref[:, 7:168, 40:243], gen[:, 7:168, 40:243]),
             "rendered 331x257": (ref[:, 100:431, 3:260], gen[:, 100:431, 3:260])}
    for size in ((512, 512), (256, 256), (161, 161), (163, 200), (201, 170)):
        a = np.random.default_rng(size[0]).integers(0, 256, (2, *size, 3), dtype=np.uint8)
        b = np.stack([noisy(a[:1], 30.0)[0], blurred(a[1:], 2.0)[0]])
        cases[f"random {size}"] = (a, b)
    metric = MS.MSSSIM()
    assert metric.unavailable_reason() is None
    worst = 0.0
    for name, (a, b) in cases.items():
        a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
        ours = metric.pair_values(a, b)
        with torch.inference_mode():
            theirs = piq.multi_scale_ssim(to01(a), to01(b), data_range=1.0,
                                          reduction="none").double().numpy()
        assert np.allclose(ours, theirs, rtol=0, atol=1e-4), name
        if a.shape[1] * a.shape[2] <= 256 * 256:  # (piq in float64 is slow at 512²)
            with torch.inference_mode():
                exact = piq.multi_scale_ssim(to01(a).double(), to01(b).double(),
                                             data_range=1.0, reduction="none").numpy()
            assert np.abs(ours - exact).max() <= np.abs(theirs - exact).max() + 2e-6, name
        worst = max(worst, float(np.abs(ours - theirs).max()))
    assert worst < 2e-5  # in practice: a few 1e-6


def test_fsim_phase_congruency_is_piqs_bit_for_bit():
    """The phase congruency with the filter bank's own terms built once per size (and planar
    even/odd responses) is piq's ``_phase_congruency``, bit for bit, at even and odd sizes."""
    from piq.fsim import _phase_congruency

    d = FV._defaults(piq.fsim)
    for size in (64, 131):
        frames = np.concatenate([structured(2, size), random_frames(2, size, 3)])
        x = (to01(frames) * 255)[:, :1]
        with torch.inference_mode():
            bank = FV._fsim_filters(x, d)
            assert bank is FV._fsim_filters(x, d)
            theirs = _phase_congruency(x, bank[0], d["scales"], d["orientations"], d["k"])
            ours = FV._phase_congruency(x, bank, d["scales"], d["orientations"], d["k"])
        assert torch.equal(ours, theirs), size


def test_ms_ssim_needs_161_pixels():
    frames = structured(2, 128)
    assert np.isnan(MS.MSSSIM().pair_values(frames, frames)).all()
    assert MS.MS_SSIM_MIN_SIZE == (11 - 1) * 2 ** (len(MS.MS_SSIM_WEIGHTS) - 1) + 1


# ----------------------------------------------------------------------------- per-frame paths
def _batches(size: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Pair batches whose frames repeat (within the batch, on both sides, a frame on both sides)
    and whose frames do not."""
    ref = np.concatenate([structured(4, size), random_frames(2, size, 5)])
    gen = np.concatenate([noisy(structured(4, size, seed=1), 10.0), random_frames(2, size, 6)])
    return {"distinct": (ref, gen),
            "repeats": (ref[[0, 0, 1, 2, 2, 5, 0]], gen[[0, 1, 1, 3, 3, 4, 0]]),
            "same frame both sides": (ref[[0, 1, 2]], ref[[0, 2, 1]]),
            "reversed": (ref[::-1].copy(), gen[[5, 3, 1, 0, 2, 4]])}


def _per_pair(metric, ref: np.ndarray, gen: np.ndarray) -> np.ndarray:
    """The straightforward computation, one pair at a time, nothing shared."""
    from visphy_plugins.metrics.pixel import ssim_frame

    out = []
    for a, b in zip(ref, gen):
        if metric.name == "ssim":
            out.append(ssim_frame(a, b))
            continue
        x, y = to01(a[None]), to01(b[None])
        with torch.inference_mode():
            if metric.name in PIQ_CALLS:
                out.append(float(PIQ_CALLS[metric.name](x, y)[0]))
            else:  # the package's own forward on the working-size frames
                out.append(float(metric.forward(metric.model(), metric._tensor(a[None]),
                                                metric._tensor(b[None])).flatten()[0]))
    return np.array(out)


@pytest.mark.parametrize("name", ["ssim", "fsim", "vsi", "st_lpips", "lpips"])
def test_per_frame_paths_equal_the_per_pair_computation(name, weight_dir, monkeypatch):
    """Each frame's share computed once (in the batch and across calls, as the scorer asks for
    a scene's pairings one after the other) gives the per-pair values: SSIM bit for bit, the
    torch metrics to 1e-6; the cache's hits are real, and a disabled cache (for SSIM: a batch
    too large to keep) changes nothing."""
    if name == "lpips":
        save_alexnet(weight_dir / "alexnet-owt-7be5be79.pth", seed=0)
    metric = SSIM() if name == "ssim" else {"fsim": FV.FSIM, "vsi": FV.VSI, "st_lpips": LD.STLPIPS,
                                             "lpips": LD.LPIPS}[name]()
    assert metric.unavailable_reason() is None
    size = 96 if name in ("ssim", "st_lpips", "lpips") else 64
    atol = 0.0 if name == "ssim" else 1e-6
    batches = _batches(size)
    expected = {k: _per_pair(metric, *v) for k, v in batches.items()}
    for cache_bytes in (_T.FRAME_CACHE_BYTES, 0):
        monkeypatch.setattr(_T, "FRAME_CACHE_BYTES", cache_bytes)
        _T.clear_frame_cache()
        seen: dict[str, set] = {"reference": set(), "generated": set()}
        for k, (ref, gen) in batches.items():
            before = dict(_T.frame_cache_stats)
            ours = metric.pair_values(ref, gen)
            assert np.allclose(ours, expected[k], rtol=0, atol=atol), (k, ours - expected[k])
            if not cache_bytes:  # (SSIM: moments pair by pair; the others: per chunk)
                continue
            hits = _T.frame_cache_stats["hits"] - before["hits"]
            misses = _T.frame_cache_stats["misses"] - before["misses"]
            assert hits + misses == 2 * len(ref)
            # each distinct frame of a side is computed once, unless a call before had it
            new = {side: {f.tobytes() for f in frames} - seen[side]
                   for side, frames in (("reference", ref), ("generated", gen))}
            assert misses == len(new["reference"]) + len(new["generated"]), k
            for side in seen:
                seen[side] |= new[side]


def test_ssim_keeps_moments_only_for_batches_that_fit(monkeypatch):
    """More pairs than `PAIR_CHUNK`; a batch whose frames' moments would not fit in the cache
    (a 3D scene's 75 pairs) is computed pair by pair, nothing kept, with the same values."""
    from visphy_plugins.metrics import pixel

    ref = np.concatenate([structured(6, 64), random_frames(5, 64, 8)])
    gen = noisy(ref, 12.0)
    assert len(ref) > pixel.PAIR_CHUNK
    expected = [ssim_frame(a, b) for a, b in zip(ref, gen)]
    before = dict(_T.frame_cache_stats)
    assert SSIM().pair_values(ref, gen).tolist() == expected
    assert _T.frame_cache_stats["misses"] - before["misses"] == 2 * len(ref)
    monkeypatch.setattr(_T, "FRAME_CACHE_BYTES", 2 * len(ref) * 4 * 2 * 64 * 64 * 4 - 1)
    _T.clear_frame_cache()
    before = dict(_T.frame_cache_stats)
    assert SSIM().pair_values(ref, gen[::-1].copy()).tolist() == \
        [ssim_frame(a, b) for a, b in zip(ref, gen[::-1])]
    assert _T.frame_cache_stats == before and _T._frames_bytes == 0


def test_per_frame_cache_dedupes_keeps_sides_apart_and_stays_in_its_budget(monkeypatch):
    calls = []

    def compute(batch):
        calls.append(len(batch))
        return [np.full(1000, f.mean(), np.float64) for f in batch]  # 8000 bytes each

    frames = random_frames(5, 8, 1)
    batch = frames[[0, 1, 0, 2, 1, 3]]
    out = _T.per_frame(batch, ("t", "reference"), compute, chunk=2)
    assert calls == [2, 2]  # 4 distinct frames in chunks of 2
    assert [o[0] for o in out] == [f.mean() for f in batch]
    assert out[0] is out[2]
    _T.per_frame(batch, ("t", "reference"), compute)
    assert calls == [2, 2]  # all cached
    _T.per_frame(batch[:1], ("t", "generated"), compute)
    assert calls == [2, 2, 1]  # the other side: its own entry
    monkeypatch.setattr(_T, "FRAME_CACHE_BYTES", 3 * 8000)
    _T.clear_frame_cache()
    _T.per_frame(frames, ("t", "reference"), compute)  # 5 frames, room for the last 3
    calls.clear()
    _T.per_frame(frames[[2, 3, 4]], ("t", "reference"), compute)
    assert calls == []
    _T.per_frame(frames[:2], ("t", "reference"), compute)
    assert calls == [2]
    assert _T._frames_bytes <= 3 * 8000
    monkeypatch.setenv(_T.FRAME_CACHE_ENV, "1.5")
    assert _T._cache_bytes() == int(1.5 * 2**20)
    monkeypatch.setenv(_T.FRAME_CACHE_ENV, "lots")
    with pytest.raises(ValueError, match=_T.FRAME_CACHE_ENV):
        _T._cache_bytes()
    monkeypatch.delenv(_T.FRAME_CACHE_ENV)
    assert _T._cache_bytes() == 128 * 2**20


# ----------------------------------------------------------------------------- ST-LPIPS
def stlpips_package():
    from stlpips_pytorch import utils

    stlpips = LD._import_stlpips()
    model = stlpips.LPIPS(net="alex", variant="shift_tolerant", verbose=False)  # its own loader
    return model.eval(), utils


#: ST-LPIPS (alex, shift-tolerant, vST0.0) of structured(3, 64) against the frames below, as the
#: stlpips-pytorch 0.0.2 API computes them (stlpips.LPIPS(net="alex", variant="shift_tolerant"),
#: utils.im2tensor): a regression anchor for the packaged net.
STLPIPS_REFERENCE = {
    "noisy": [0.17538967728614807, 0.13974657654762268, 0.1489482969045639],
    "shift4": [0.03942910581827164, 0.03900952637195587, 0.04190894961357117],
}


def st_cases() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    ref = structured(3, 64)
    return {"noisy": (ref, noisy(ref, 20.0)), "shift4": (ref, np.roll(ref, 4, axis=2))}


def test_st_lpips_is_available_with_every_parameter_loaded():
    metric = LD.STLPIPS()
    assert metric.unavailable_reason() is None
    assert (metric.kind, metric.direction, metric.family) == (PAIRS, LOWER, "perceptual")
    path = metric.files().paths[0]
    assert path.name == "alex_shift_tolerant.pth" and "stlpips_pytorch" in str(path)
    state = torch.load(path, map_location="cpu", weights_only=True)
    model = metric.model()
    own = model.state_dict()
    for name, value in own.items():
        src = LD._lins_alias(name)
        assert torch.equal(value.cpu(), state[src]), name  # backbone, blur filters, linear layers
    assert {LD._lins_alias(n) for n in own} == set(state)
    assert any(n.startswith("net.slice1.0.") for n in own)
    assert "weights=" in metric.identity() and "size=256" in metric.identity()


def test_st_lpips_reproduces_the_package_api():
    model, utils = stlpips_package()
    metric = LD.STLPIPS()
    for name, (ref, gen) in st_cases().items():
        ours = metric.pair_values(ref, gen)
        with torch.no_grad():
            theirs = np.array([model(utils.im2tensor(a), utils.im2tensor(b)).item()
                               for a, b in zip(ref, gen)])
        assert np.allclose(ours, theirs, rtol=0, atol=1e-6), name
        assert np.allclose(ours, STLPIPS_REFERENCE[name], rtol=0, atol=1e-5), name


def test_st_lpips_works_at_256_on_larger_frames():
    """512² frames are area-averaged to 256² (exact 2×2 means) before the net."""
    model, _ = stlpips_package()
    ref = structured(1, 512)
    gen = np.roll(ref, 6, axis=1)
    ours = LD.STLPIPS().pair_values(ref, gen)
    half = lambda f: to01(f).view(1, 3, 256, 2, 256, 2).mean((3, 5)) * 2 - 1  # noqa: E731
    with torch.no_grad():
        theirs = model(half(ref), half(gen)).flatten().double().numpy()
    assert np.allclose(ours, theirs, rtol=0, atol=1e-6)


def test_st_lpips_identical_zero_shift_small_different_large():
    metric = LD.STLPIPS()
    ref = structured(2, 96)
    assert np.allclose(metric.pair_values(ref, ref), 0.0, atol=1e-7)
    shifted = np.roll(ref, 1, axis=2)
    other = structured(2, 96, seed=9)[:, ::-1].copy()
    d_shift = metric.pair_values(ref, shifted)
    d_other = metric.pair_values(ref, other)
    assert (d_shift < 0.02).all() and (d_other > 0.1).all() and (d_other > 10 * d_shift).all()


def test_st_lpips_checkpoint_in_the_weight_dir_replaces_the_packaged_one(weight_dir):
    import shutil

    metric = LD.STLPIPS()
    packaged = metric.identity()
    assert metric.unavailable_reason() is None  # the packaged net matches its recorded SHA-256
    # an identical copy in the weight dir is used in its place (same content, same identity)
    shutil.copyfile(LD.stlpips_packaged_file("alex"), weight_dir / "alex_shift_tolerant.pth")
    assert metric.files().paths[0] == weight_dir / "alex_shift_tolerant.pth"
    assert metric.unavailable_reason() is None and metric.identity() == packaged
    # another net under that name is refused ...
    stlpips = LD._import_stlpips()
    torch.manual_seed(3)
    net = stlpips.LPIPS(net="alex", variant="shift_tolerant", pretrained=False, verbose=False)
    sd = {k: v for k, v in net.state_dict().items() if not k.startswith("lins.")}
    torch.save(sd, weight_dir / "alex_shift_tolerant.pth")
    got = weights.sha256(weight_dir / "alex_shift_tolerant.pth")
    assert metric.unavailable_reason() == (
        f"checksum mismatch ({weight_dir / 'alex_shift_tolerant.pth'}: expected b356b382f960, "
        f"got {got[:12]})")
    with pytest.raises(RuntimeError, match="checksum mismatch"):
        metric.model()
    # ... unless it is the published file (here: the test says so), then it is what loads
    publish(weight_dir / "alex_shift_tolerant.pth", LD.STLPIPS_KEY)
    assert metric.identity() != packaged
    ref = structured(2, 64)
    v = metric.pair_values(ref, noisy(ref, 20.0))
    assert np.isfinite(v).all()
    assert torch.equal(metric.model().net.slice1[0].weight, sd["net.slice1.0.weight"])


def test_st_lpips_without_its_net_is_unavailable(weight_dir, monkeypatch):
    monkeypatch.setattr(LD, "stlpips_packaged_file", lambda net="alex": None)
    reason = LD.STLPIPS().unavailable_reason()
    assert "alex_shift_tolerant.pth" in reason and "metrics.weights_dir" in reason


# ----------------------------------------------------------------------------- LPIPS / DISTS
def test_lpips_loads_alexnet_from_the_weight_dir(weight_dir, monkeypatch):
    import types

    import lpips
    from torchvision.models.alexnet import AlexNet

    metric = LD.LPIPS()
    sd = save_alexnet(weight_dir / "alexnet-owt-7be5be79.pth", seed=0)
    assert metric.unavailable_reason() is None
    ref = structured(3, 64)
    gen = noisy(ref, 20.0)
    ours = metric.pair_values(ref, gen)
    assert ours.shape == (3,) and np.isfinite(ours).all() and (ours > 0).all()
    assert np.allclose(metric.pair_values(ref, ref), 0.0, atol=1e-7)
    # the lpips package's own construction with the same backbone gives the same values
    def alexnet_with(*args, **kwargs):  # what lpips uses of torchvision's alexnet: features
        features = AlexNet().features
        features.load_state_dict({k[len("features."):]: v for k, v in sd.items()})
        return types.SimpleNamespace(features=features)

    monkeypatch.setattr(lpips.pretrained_networks.tv, "alexnet", alexnet_with)
    upstream = lpips.LPIPS(net="alex", version="0.1", verbose=False).eval()
    with torch.no_grad():
        theirs = upstream(to01(ref) * 2 - 1, to01(gen) * 2 - 1).flatten().double().numpy()
    assert np.allclose(ours, theirs, rtol=0, atol=1e-6)
    # a different checkpoint: a different identity and different values
    ident = metric.identity()
    save_alexnet(weight_dir / "alexnet-owt-7be5be79.pth", seed=1)
    assert metric.identity() != ident
    assert not np.allclose(metric.pair_values(ref, gen), ours)
    assert "alexnet-owt-7be5be79.pth" in metric.weights


def test_dists_loads_vgg16_and_alpha_beta_from_the_weight_dir(weight_dir, monkeypatch):
    import types

    import piq.perceptual as pp
    from torchvision.models.vgg import cfgs, make_layers

    metric = LD.DISTS()
    assert metric.direction == LOWER and metric.score_range == (0.0, 1.0)
    vgg = save_vgg16_features(weight_dir / "vgg16-397923af.pth", seed=0)
    ab = save_dists_ab(weight_dir / "dists_weights.pt", seed=0)
    assert metric.unavailable_reason() is None
    ref = structured(3, 64)
    gen = noisy(ref, 20.0)
    ours = metric.pair_values(ref, gen)
    assert np.isfinite(ours).all() and (ours > 0).all()
    assert np.allclose(metric.pair_values(ref, ref), 0.0, atol=1e-6)
    # piq.DISTS itself, its two downloads answered with the same files
    def vgg16_with(*args, **kwargs):  # what piq uses of torchvision's vgg16: its features
        features = make_layers(cfgs["D"])
        features.load_state_dict({k[len("features."):]: v for k, v in vgg.items()})
        return types.SimpleNamespace(features=features)

    monkeypatch.setattr(pp, "vgg16", vgg16_with)
    total = ab["alpha"].sum() + ab["beta"].sum()
    monkeypatch.setattr(pp.torch.hub, "load_state_dict_from_url",
                        lambda *a, **k: {"alpha": ab["alpha"] / total, "beta": ab["beta"] / total})
    upstream = piq.DISTS(reduction="none")
    with torch.no_grad():
        theirs = upstream(to01(ref), to01(gen)).double().numpy()
    assert np.allclose(ours, theirs, rtol=0, atol=1e-6)
    ident = metric.identity()
    save_dists_ab(weight_dir / "dists_weights.pt", seed=1)
    assert metric.identity() != ident


def test_a_wrong_file_under_a_published_name_is_never_used(weight_dir, tmp_path, monkeypatch):
    """torchvision's checkpoints are checked against the hash prefix in their names, the
    packaged LPIPS linear layers against their recorded SHA-256, piq's DISTS file needs one
    recorded in SHA256SUMS: otherwise the metric is unavailable, never a number."""
    import shutil

    save_alexnet(weight_dir / "alexnet-owt-7be5be79.pth", seed=0, published=False)
    got = weights.sha256(weight_dir / "alexnet-owt-7be5be79.pth")
    reason = LD.LPIPS().unavailable_reason()
    assert reason == (f"checksum mismatch ({weight_dir / 'alexnet-owt-7be5be79.pth'}: "
                      f"expected 7be5be79, got {got[:8]})")
    ref = structured(3, 32)
    scores, unavailable = score_scene(scene_for(3, 32), ref, noisy(ref, 5.0), [LD.LPIPS()], None,
                                      None, Cache(tmp_path / "cache"))
    for col in ("lpips", "lpips.aligned", "paper.lpips"):
        assert scores[col] is None and unavailable[col] == reason
    with pytest.raises(RuntimeError, match="checksum mismatch"):
        LD.LPIPS().pair_values(ref, ref)
    # the packaged linear layers are checked too
    publish(weight_dir / "alexnet-owt-7be5be79.pth")
    assert LD.LPIPS().unavailable_reason() is None
    lins = tmp_path / "alex.pth"
    shutil.copyfile(LD.lpips_linear_file("alex"), lins)
    with open(lins, "ab") as f:
        f.write(b"\0")
    monkeypatch.setattr(LD, "lpips_linear_file", lambda net="alex": lins)
    assert LD.LPIPS().unavailable_reason().startswith(
        f"checksum mismatch ({lins}: expected df73285e35b2, got ")
    # DISTS' alpha/beta: no published SHA-256 but the user's SHA256SUMS line
    save_vgg16_features(weight_dir / "vgg16-397923af.pth", seed=0)
    save_dists_ab(weight_dir / "dists_weights.pt", seed=0, published=False)
    reason = LD.DISTS().unavailable_reason()
    assert reason.startswith("no published SHA-256 for dists_weights.pt")
    sha = weights.sha256(weight_dir / "dists_weights.pt")
    (weight_dir / "SHA256SUMS").write_text(f"{sha}  dists_weights.pt\n")
    assert LD.DISTS().unavailable_reason() is None


@pytest.mark.parametrize("cls,files", [(LD.LPIPS, ["alexnet-owt-7be5be79.pth"]),
                                       (LD.DISTS, ["vgg16-397923af.pth", "dists_weights.pt"])])
def test_missing_weights_make_the_metric_unavailable_never_a_number(weight_dir, tmp_path,
                                                                    cls, files):
    metric = cls()
    reason = metric.unavailable_reason()
    assert reason and "weights not found" in reason
    for f in files:
        assert f in reason
    assert "metrics.weights_dir" in reason and str(weight_dir) in reason
    ref = structured(5, 32)
    scores, unavailable = score_scene(scene_for(5, 32), ref, noisy(ref, 5.0), [metric], None,
                                      None, Cache(tmp_path / "cache"))
    for col in (metric.name, f"{metric.name}.aligned", f"paper.{metric.name}"):
        assert scores[col] is None and unavailable[col] == reason


def test_dists_missing_only_alpha_beta_names_that_file(weight_dir):
    save_vgg16_features(weight_dir / "vgg16-397923af.pth", seed=0)
    reason = LD.DISTS().unavailable_reason()
    assert "put dists_weights.pt in metrics.weights_dir" in reason


# ----------------------------------------------------------------------------- behaviour
def _monotone(values, increasing: bool) -> bool:
    d = np.diff(values)
    return bool((d > 0).all() if increasing else (d < 0).all())


def test_metrics_move_the_right_way_with_noise_and_blur(weight_dir):
    save_alexnet(weight_dir / "alexnet-owt-7be5be79.pth", seed=0)
    save_vgg16_features(weight_dir / "vgg16-397923af.pth", seed=0)
    save_dists_ab(weight_dir / "dists_weights.pt", seed=0)
    for metric in (MS.MSSSIM(), FV.FSIM(), FV.VSI(), LD.STLPIPS(), LD.LPIPS(), LD.DISTS()):
        ref = structured(1, 176 if metric.name == "ms_ssim" else 96)
        for kind, gens in {"noise": [noisy(ref, s) for s in (4.0, 12.0, 30.0, 60.0)],
                           "blur": [blurred(ref, s) for s in (0.7, 1.5, 3.0, 6.0)]}.items():
            values = metric.pair_values(np.repeat(ref, 4, axis=0), np.concatenate(gens))
            assert _monotone(values, increasing=metric.direction == LOWER), \
                (metric.name, kind, values)


def test_registered_with_direction_and_range():
    registered = []
    for module in (MS, FV, LD):
        module.visphy_register_metrics(registered.append)
    expected = {"ms_ssim": (HIGHER, (0.0, 1.0)), "fsim": (HIGHER, (0.0, 1.0)),
                "vsi": (HIGHER, (0.0, 1.0)), "lpips": (LOWER, (0.0, float("inf"))),
                "st_lpips": (LOWER, (0.0, float("inf"))), "dists": (LOWER, (0.0, 1.0))}
    assert sorted(m.name for m in registered) == sorted(expected)
    for metric in registered:
        d = metric.describe()
        assert (d["direction"], tuple(d["range"]), d["family"], d["kind"]) == \
            (*expected[metric.name], "perceptual", PAIRS)
        assert d["max_pairs"] == metric.max_pairs and d["max_pairs"] is not None
    st = next(m for m in registered if m.name == "st_lpips").describe()
    assert st["unavailable"] is None and "alex_shift_tolerant.pth" in st["weights"]


def test_torch_threads_follow_the_environment_and_the_block(monkeypatch):
    monkeypatch.setenv(_T.THREADS_ENV, "1")
    assert _T.default_threads() == 1
    monkeypatch.setenv(_T.THREADS_ENV, "not a number")
    with pytest.raises(ValueError, match=_T.THREADS_ENV):
        _T.default_threads()
    monkeypatch.delenv(_T.THREADS_ENV)
    import os

    assert _T.default_threads() == len(os.sched_getaffinity(0))
    before = torch.get_num_threads()
    with _T.threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with _T.threads(before + 5):  # never more than the process's setting
        assert torch.get_num_threads() == before

