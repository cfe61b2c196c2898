"""Motion metrics (plugins/metrics/motion.py): DIS and RAFT optical flow of the generated clip
against the reference's, over every consecutive pair of a pairing."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from scipy.stats import spearmanr

from visphy_core.api import weights
from visphy_core.api.metrics import LOWER, SEQUENCE, MetricInput
from visphy_core.api.scene import ClipInfo, Scene
from visphy_core.infra.cache import Cache
from visphy_core.scoring.alignment import Alignment, unaligned
from visphy_core.scoring.score import ScoringProtocol, score_scene
from visphy_plugins.metrics import motion
from visphy_plugins.metrics.motion import (
    DIS_NAMES,
    RAFT_NAMES,
    RAFT_WEIGHT_NAMES,
    DISFlow,
    motion_metrics,
    pair_errors,
    sequence_errors,
)

DIS_METRICS = [m for m in motion_metrics() if m.name.endswith("_dis")]
RAFT_METRICS = [m for m in motion_metrics() if m.name.startswith("raft_")]
VIEWS = ("", ".aligned", "paper.")


def col(name: str, view: str) -> str:
    return f"paper.{name}" if view == "paper." else name + view


def scene_for(n: int, size: int, fps: float = 5.0) -> Scene:
    return Scene(scene_id="m0", dim="2d", clip=ClipInfo(fps=fps, n_frames=n, width=size,
                                                        height=size), video_path=Path("none.mp4"))


def texture(size: int, seed: int = 0, sigma: float = 3.0) -> np.ndarray:
    g = gaussian_filter(np.random.default_rng(seed).random((size, size)), sigma)
    g = (g - g.mean()) / g.std()
    return np.repeat((128 + 45 * g).clip(0, 255).astype(np.uint8)[..., None], 3, axis=2)


def disk_clip(n: int, velocity: tuple[float, float], size: int = 128, radius: float = 14,
              start: tuple[float, float] = (40, 50)) -> np.ndarray:
    """A red disk on a light flat background (the benchmark's look), moving at ``velocity``
    pixels a frame (anti-aliased, sub-pixel positions)."""
    frames = np.empty((n, size, size, 3), np.uint8)
    for k in range(n):
        f = np.full((size, size, 3), (240, 240, 244), np.uint8)
        x, y = start[0] + velocity[0] * k, start[1] + velocity[1] * k
        cv2.circle(f, (int(round(x * 16)), int(round(y * 16))), int(radius * 16), (220, 60, 50),
                   -1, lineType=cv2.LINE_AA, shift=4)
        frames[k] = f
    return frames


def inp_of(ref: np.ndarray, gen: np.ndarray) -> MetricInput:
    return MetricInput(scene=scene_for(len(ref), ref.shape[1]), reference=ref, generated=gen)


def scores_of(ref, gen, metrics):
    """The unaligned values of ``metrics`` (sharing one scene's memo, as the scorer does)."""
    inp = inp_of(ref, gen)
    return {m.name: m.compute_sequence(inp, unaligned(len(ref), len(gen))) for m in metrics}


# ----------------------------------------------------------------------------- the contract
def test_twelve_sequence_metrics_registered():
    registered = []
    motion.visphy_register_metrics(registered.append)
    names = [m.name for m in registered]
    assert names == [
        "flow_epe_dis", "flow_angle_dis", "flow_mag_diff_dis", "flow_epe_moving_dis",
        "flow_angle_moving_dis", "flow_mag_diff_moving_dis",
        "raft_epe", "raft_angle", "raft_mag_diff", "raft_epe_moving", "raft_angle_moving",
        "raft_mag_diff_moving"]
    assert sorted(DIS_NAMES.values()) + sorted(RAFT_NAMES.values()) == \
        sorted(names[:6]) + sorted(names[6:])
    for m in registered:
        assert (m.family, m.kind, m.direction) == ("motion", SEQUENCE, LOWER)
    assert all(m.weights is None and m.unavailable_reason() is None for m in registered[:6])
    assert "dis" in registered[0].identity() and "raft" not in registered[0].identity().lower()


def test_pair_errors_definitions():
    z = np.zeros((2, 4, 4), np.float32)
    right = z.copy()
    right[0] = 3.0  # 3 px to the right everywhere
    errs = pair_errors(right, z)
    assert errs[0] == pytest.approx(3.0) and errs[2] == pytest.approx(3.0)
    # space-time angle between (3, 0, 1) and (0, 0, 1)
    assert errs[1] == pytest.approx(math.degrees(math.atan(3.0)), rel=1e-5)
    assert errs[3:] == pytest.approx(errs[:3])  # every pixel moves
    left = -right
    opposite = pair_errors(right, left)
    assert opposite[0] == pytest.approx(6.0) and opposite[2] == pytest.approx(0.0)
    assert opposite[1] == pytest.approx(math.degrees(math.acos(-8 / 10)), rel=1e-5)
    # both still: 0 error everywhere, also over the (empty) moving pixels
    assert np.all(pair_errors(z, z) == 0)
    half = z.copy()
    half[0, :2] = 1.0  # half the pixels move 1 px in the reference, none in the generated
    e = pair_errors(half, z)
    assert e[0] == pytest.approx(0.5) and e[3] == pytest.approx(1.0)


# ----------------------------------------------------------------------------- DIS
@pytest.mark.parametrize("size", [256, 512])
def test_dis_recovers_a_translation_in_original_pixels(size):
    big = texture(size + 16, seed=1, sigma=3.0 * size / 256)
    dx, dy = 3, -2  # content moves 3 px right and 2 px up
    a = big[8:8 + size, 8:8 + size]
    b = big[8 - dy:8 - dy + size, 8 - dx:8 - dx + size]
    clip = np.stack([a, b])
    (flow,) = DISFlow().flows(inp_of(clip, clip), [("ref", 0, 1)])
    assert flow.shape == (2, 256, 256)  # the working resolution, values in original pixels
    m = 32
    u, v = flow[0, m:-m, m:-m], flow[1, m:-m, m:-m]
    assert np.median(u) == pytest.approx(dx, abs=0.3)
    assert np.median(v) == pytest.approx(dy, abs=0.3)
    assert np.mean(np.hypot(u - dx, v - dy)) < 0.5


def test_identical_clips_score_zero_in_every_pairing(tmp_path):
    ref = disk_clip(17, (4.0, 1.5))
    scores, unavailable = score_scene(scene_for(17, 128), ref, ref.copy(), DIS_METRICS, None,
                                      None, Cache(tmp_path / "c"))
    assert unavailable == {}
    for m in DIS_METRICS:
        for v in VIEWS:
            assert scores[col(m.name, v)] == 0.0


def test_opposite_motion_is_far_worse_than_slightly_slower():
    ref = disk_clip(9, (5.0, 0.0), start=(64, 60))
    slower = disk_clip(9, (4.5, 0.0), start=(64, 60))
    opposite = disk_clip(9, (-5.0, 0.0), start=(64, 60))
    s = scores_of(ref, slower, DIS_METRICS)
    o = scores_of(ref, opposite, DIS_METRICS)
    for stat in ("epe", "epe_moving", "angle", "angle_moving"):
        assert o[DIS_NAMES[stat]] > 3 * s[DIS_NAMES[stat]] > 0, stat
    assert o["flow_epe_moving_dis"] > 3.0  # 10 px apart on the disk, less on its halo


def test_errors_grow_with_the_velocity_mismatch():
    v = (3.0, 1.0)
    ref = disk_clip(7, v)
    values = {name: [] for name in ("flow_epe_dis", "flow_epe_moving_dis",
                                    "flow_mag_diff_moving_dis")}
    for k in range(1, 6):
        f = 1 + 0.2 * k
        s = scores_of(ref, disk_clip(7, (v[0] * f, v[1] * f)), DIS_METRICS)
        for name in values:
            values[name].append(s[name])
    for name, vals in values.items():
        assert spearmanr(range(5), vals).statistic >= 0.9, (name, vals)
        assert vals[-1] > 2 * vals[0] > 0, (name, vals)


def test_every_consecutive_pair_is_used():
    ref = disk_clip(8, (3.0, 0.0))
    gen = ref.copy()
    gen[-1] = disk_clip(8, (3.0, 3.0))[-1]  # only the last step differs (it drops 21 px)
    inp = inp_of(ref, gen)
    a = unaligned(8, 8)
    errs = sequence_errors(inp, a, DISFlow())
    assert errs.shape == (7, 6)
    assert np.all(errs[:-1] == 0) and errs[-1, 0] > 0 and errs[-1, 3] > 1.0
    for m in DIS_METRICS:
        assert m.compute_sequence(inp, a) == pytest.approx(errs[:, m.column].mean())
        assert m.compute_sequence(inp, a) > 0
    # the paper's sampling: pairs (0,0),(3,3),(6,6) -> flows 0→3 and 3→6, the last step unseen
    paper = Alignment(np.array([0, 3, 6]), np.array([0, 3, 6]))
    assert sequence_errors(inp, paper, DISFlow()).shape == (2, 6)
    assert all(m.compute_sequence(inp, paper) == 0 for m in DIS_METRICS)


def test_fewer_than_two_pairs_is_nan():
    ref = disk_clip(3, (3.0, 0.0))
    inp = inp_of(ref, ref)
    for a in (Alignment(np.array([1]), np.array([2])), Alignment(np.zeros(0, int),
                                                                 np.zeros(0, int))):
        assert all(math.isnan(m.compute_sequence(inp, a)) for m in DIS_METRICS)


def test_flows_are_shared_by_metrics_and_pairings(monkeypatch):
    ref = disk_clip(9, (3.0, 1.0))
    gen = disk_clip(9, (3.6, 1.0))
    computed: list = []
    original = DISFlow.flows

    def counting(self, inp, todo):
        computed.extend(todo)
        return original(self, inp, todo)

    monkeypatch.setattr(DISFlow, "flows", counting)
    inp = inp_of(ref, gen)
    a = unaligned(9, 9)
    aligned_at_0 = Alignment(np.arange(9), np.arange(9), method="offset")
    shifted = Alignment(np.arange(8), np.arange(1, 9), offset=1, method="offset")
    paper = Alignment(np.array([0, 3, 6]), np.array([0, 3, 6]), method="offset")
    for al in (a, aligned_at_0, shifted, paper):
        for m in DIS_METRICS:
            m.compute_sequence(inp, al)
    assert len(computed) == len(set(computed))  # no flow computed twice
    # 8 reference + 8 generated consecutive flows, then the paper's 2 + 2; the shifted
    # pairing reuses the consecutive flows of both clips
    assert len(computed) == 8 + 8 + 2 + 2


# ----------------------------------------------------------------------------- RAFT
@pytest.fixture
def no_weights(tmp_path, monkeypatch):
    monkeypatch.delenv("VISPHY_WEIGHTS", raising=False)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    weights.configure(tmp_path / "empty")
    yield tmp_path / "empty"
    weights.configure(None)


def test_raft_without_weights_is_unavailable_everywhere(no_weights, tmp_path):
    reason = RAFT_METRICS[0].unavailable_reason()
    assert reason and "raft_large_C_T_SKHT_V2-ff5fadd5.pth" in reason
    assert "metrics.weights_dir" in reason and str(no_weights) in reason
    ref = disk_clip(5, (3.0, 0.0))
    scores, unavailable = score_scene(scene_for(5, 128), ref, disk_clip(5, (2.0, 0.0)),
                                      DIS_METRICS[:1] + RAFT_METRICS, None, None,
                                      Cache(tmp_path / "c"),
                                      protocol=ScoringProtocol(paper=False))
    for m in RAFT_METRICS:
        for v in ("", ".aligned"):
            assert scores[m.name + v] is None and unavailable[m.name + v] == reason
    assert scores["flow_epe_dis"] > 0 and "flow_epe_dis" not in unavailable


@pytest.fixture(scope="module")
def fake_raft_dir(tmp_path_factory):
    """The real raft_large architecture at random init, saved under the checkpoint's name."""
    torch = pytest.importorskip("torch")
    from torchvision.models.optical_flow import raft_large

    d = tmp_path_factory.mktemp("raft_weights")
    torch.manual_seed(0)
    torch.save(raft_large(weights=None, progress=False).state_dict(), d / RAFT_WEIGHT_NAMES[0])
    return d


@pytest.fixture
def fake_raft(fake_raft_dir, monkeypatch):
    monkeypatch.delenv("VISPHY_WEIGHTS", raising=False)
    weights.configure(fake_raft_dir)
    # the random-init stand-in passes as the published checkpoint, for the test only
    path = fake_raft_dir / RAFT_WEIGHT_NAMES[0]
    monkeypatch.setitem(weights.PUBLISHED, RAFT_WEIGHT_NAMES[0],
                        weights.Published(weights.sha256(path), "test: random init"))
    yield fake_raft_dir
    weights.configure(None)


def test_a_raft_file_that_is_not_the_published_one_is_never_used(fake_raft_dir, monkeypatch,
                                                                 tmp_path):
    """The checkpoint's name carries the start of its SHA-256 (torchvision's convention): the
    random file under that name fails the check, every RAFT metric is unavailable with the
    mismatch, and loading it is refused."""
    monkeypatch.delenv("VISPHY_WEIGHTS", raising=False)
    weights.configure(fake_raft_dir)
    try:
        path = fake_raft_dir / RAFT_WEIGHT_NAMES[0]
        reason = RAFT_METRICS[0].unavailable_reason()
        assert reason == (f"checksum mismatch ({path}: expected ff5fadd5, "
                          f"got {weights.sha256(path)[:8]})")
        assert all(m.unavailable_reason() == reason for m in RAFT_METRICS)
        with pytest.raises(RuntimeError, match="checksum mismatch"):
            motion.load_raft(path, "cpu")
        ref = disk_clip(5, (3.0, 0.0))
        scores, unavailable = score_scene(scene_for(5, 128), ref, disk_clip(5, (2.0, 0.0)),
                                          RAFT_METRICS[:1], None, None, Cache(tmp_path / "c"),
                                          protocol=ScoringProtocol(paper=False))
        assert scores["raft_epe"] is None and unavailable["raft_epe"] == reason
        # torchvision's other RAFT checkpoints are other models: not searched for
        assert RAFT_WEIGHT_NAMES == ("raft_large_C_T_SKHT_V2-ff5fadd5.pth",)
    finally:
        weights.configure(None)


def test_raft_runs_the_real_architecture_on_inputs_in_minus_one_one(fake_raft, monkeypatch):
    assert all(m.unavailable_reason() is None for m in RAFT_METRICS)
    digest = weights.digest(fake_raft / RAFT_WEIGHT_NAMES[0])
    assert digest in RAFT_METRICS[0].identity()
    model = motion.load_raft(fake_raft / RAFT_WEIGHT_NAMES[0], weights.device())
    assert type(model).__name__ == "RAFT"
    seen: list[tuple[float, float, tuple]] = []
    updates: list[int] = []
    forward = model.forward

    def spy(image1, image2, num_flow_updates=12):
        for x in (image1, image2):
            seen.append((float(x.min()), float(x.max()), tuple(x.shape)))
        updates.append(num_flow_updates)
        return forward(image1, image2, num_flow_updates=num_flow_updates)

    monkeypatch.setattr(model, "forward", spy)
    estimator = RAFT_METRICS[0].estimator
    assert estimator.iterations == 12  # torchvision's default; 3 here to keep the test fast
    monkeypatch.setattr(estimator, "iterations", 3)
    # 96² (upscaled to RAFT's smallest input, 128²); the generated clip equals the reference
    # up to its last frame, so the first step compares identical flows and the second does not
    small = dict(size=96, radius=10, start=(40, 40))
    ref = disk_clip(3, (5.0, 0.0), **small)
    ref[:, :, :4] = 0  # black and white pixels reach −1 and +1
    ref[:, :, -4:] = 255
    gen = ref.copy()
    gen[2] = disk_clip(3, (-5.0, 0.0), **small)[2]
    gen[2, :, :4], gen[2, :, -4:] = 0, 255
    inp = inp_of(ref, gen)
    errs = sequence_errors(inp, unaligned(3, 3), RAFT_METRICS[0].estimator)
    assert errs.shape == (2, 6) and np.all(np.isfinite(errs))
    assert errs[0, 0] == pytest.approx(0.0, abs=1e-5)  # identical frames: 0 EPE
    assert np.all(errs[0] == pytest.approx(0.0, abs=1e-3))
    assert errs[1, 0] > 1e-3
    values = {m.name: m.compute_sequence(inp, unaligned(3, 3)) for m in RAFT_METRICS}
    assert all(np.isfinite(v) for v in values.values()), values
    assert len(seen) == 2 and updates == [3]  # one batch of the four flows, then memoised
    assert all(lo == pytest.approx(-1.0) and hi == pytest.approx(1.0) for lo, hi, _ in seen)
    assert all(shape == (4, 3, 128, 128) for *_, shape in seen)
    flow = inp.extra["motion"][("flow", RAFT_METRICS[0].estimator.config(), "ref", 0, 1)]
    assert flow.shape == (2, 128, 128) and flow.dtype == np.float32
    # the flow kept is the last refinement's, in the clip's pixels (96 px → 128 px working)
    import torch

    with torch.inference_mode():
        preds = forward(motion.raft_input(ref[:1], (128, 128)),
                        motion.raft_input(ref[1:2], (128, 128)), num_flow_updates=3)
    last = preds[-1][0].numpy() * (96 / 128)
    assert np.abs(flow - last).max() < 1e-3 * max(1.0, np.abs(last).max())
    assert np.abs(flow - preds[0][0].numpy() * (96 / 128)).max() > 1e-3
    # the model is loaded once per process
    assert motion.load_raft(fake_raft / RAFT_WEIGHT_NAMES[0], weights.device()) is model


def test_raft_preprocessing_scales_to_minus_one_one():
    frames = np.zeros((1, 100, 60, 3), np.uint8)
    frames[0, :, 30:] = 255
    x = motion.raft_input(frames, (104, 64))
    assert tuple(x.shape) == (1, 3, 104, 64)
    assert float(x.min()) == pytest.approx(-1.0) and float(x.max()) == pytest.approx(1.0)
    assert motion.RaftFlow().working_shape(512, 512) == (256, 256)
    assert motion.RaftFlow().working_shape(200, 300) == (176, 256)
    assert motion.RaftFlow().working_shape(100, 60) == (128, 128)
