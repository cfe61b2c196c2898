"""Motion-mask metrics after Physics-IQ (plugins/metrics/motion_masks.py): identical clips score 1,
a still clip 0, a few pixels off high but below 1, motion in the wrong place low; an H.264
re-encode of the ground truth ≈ 1 (the threshold ignores compression noise); a reference without
motion is NaN with its reason; and the metrics through the scorer and the CLI."""

from __future__ import annotations

import copy
import json
import math

import cv2
import numpy as np
import pytest

from conftest import run_cli
from visphy_core.api.metrics import HIGHER, LOWER, SEQUENCE, MetricInput
from visphy_core.api.scene import Scene
from visphy_core.infra.cache import Cache
from visphy_core.infra.video import ClipInfo, decode_video, encode_video
from visphy_core.scoring.alignment import EVERY_FRAME, PAPER, align, unaligned
from visphy_core.scoring.score import ScoringProtocol, score_scene
from visphy_plugins.metrics import motion_masks as M

IOUS = ("spatial_iou", "spatiotemporal_iou", "weighted_spatial_iou")
NAMES = M.NAMES
FPS = 5.0
SIZE = 256


# ------------------------------------------------------------------------------ helpers
def _scene(fps: float = FPS, n: int = 17, size: int = SIZE, sid: str = "synthetic") -> Scene:
    return Scene(scene_id=sid, dim="2d", clip=ClipInfo(fps=fps, n_frames=n, width=size,
                                                       height=size), video_path=None)


def ball_clip(path: list[tuple[float, float]], size: int = SIZE, r: int = 12,
              colour=(230, 60, 50)) -> np.ndarray:
    """A ball (anti-aliased, flat colour) along ``path`` on white, with a static black bar."""
    frames = np.full((len(path), size, size, 3), 255, np.uint8)
    for f, (x, y) in zip(frames, path):
        cv2.rectangle(f, (20, size - 30), (size - 20, size - 24), (0, 0, 0), -1)
        cv2.circle(f, (int(round(x * 16)), int(round(y * 16))), r * 16, colour, -1,
                   cv2.LINE_AA, shift=4)
    return frames


def falling(n: int = 17, x0: float = 60.0, vx: float = 8.0, g: float = 2.0) -> list:
    """A thrown ball: x grows linearly, y falls under constant acceleration (pixels/frame)."""
    return [(x0 + vx * k, 30.0 + 0.5 * g * k * k) for k in range(n)]


def values(ref: np.ndarray, gen: np.ndarray, alignment=None, scene: Scene | None = None
           ) -> dict[str, float]:
    inp = MetricInput(scene=scene or _scene(n=len(ref), size=ref.shape[1]), reference=ref,
                      generated=gen)
    a = alignment if alignment is not None else unaligned(len(ref), len(gen))
    return {m.name: m.compute_sequence(inp, a) for m in (cls() for cls in M.METRICS)}


def still(clip: np.ndarray) -> np.ndarray:
    return np.repeat(clip[:1], len(clip), axis=0)


def reencoded(clip: np.ndarray, fps: float, tmp_path, crf: int = 23) -> np.ndarray:
    path = tmp_path / f"re_{crf}.mp4"
    encode_video(clip, path, fps, crf=crf)
    frames, _ = decode_video(path)
    return frames


# ------------------------------------------------------------------------------ contract
def test_five_sequence_metrics_registered_with_their_contract():
    from visphy_core.api.registry import get_registry

    reg = get_registry()
    for name in NAMES:
        m = reg.get("metrics", name)
        assert m.kind == SEQUENCE and m.weights is None and m.unavailable_reason() is None
        assert m.score_range == (0.0, 1.0)
    for name in IOUS:
        assert reg.get("metrics", name).direction == HIGHER
        assert reg.get("metrics", name).family == "motion_mask"
    assert reg.get("metrics", "masked_mse").direction == LOWER
    assert reg.get("metrics", "masked_mse").family == "motion_mask"
    assert reg.get("metrics", "mse").direction == LOWER
    assert reg.get("metrics", "mse").family == "pixel"
    # the mask parameters are part of every cached value's key
    assert "thr=10" in reg.get("metrics", "spatial_iou").identity()


def test_the_metrics_subcommand_lists_them(tmp_path):
    out = run_cli("metrics", home=tmp_path).stdout
    for name in NAMES:
        line = next(ln for ln in out.splitlines() if f" {name} " in ln)
        assert "available" in line, line
    assert "motion_mask" in out


# ------------------------------------------------------------------------------ synthetic
def test_identical_clips_score_one_under_every_pairing():
    ref = ball_clip(falling())
    for a in (unaligned(17, 17), align(ref, ref.copy(), EVERY_FRAME), align(ref, ref, PAPER)):
        got = values(ref, ref.copy(), a)
        assert got == {"spatial_iou": 1.0, "spatiotemporal_iou": 1.0,
                       "weighted_spatial_iou": 1.0, "masked_mse": 0.0, "mse": 0.0}, a.method


def test_a_still_clip_scores_zero_on_every_iou():
    ref = ball_clip(falling())
    got = values(ref, still(ref))
    assert [got[n] for n in IOUS] == [0.0, 0.0, 0.0]
    assert got["masked_mse"] > 0.01  # the ball is missing wherever it moved


def test_a_few_pixels_off_scores_high_but_below_one():
    ref = ball_clip(falling())
    got = values(ref, ball_clip([(x + 3, y) for x, y in falling()]))
    for name in IOUS:
        assert 0.6 < got[name] < 1.0, (name, got[name])
    assert got["spatial_iou"] > 0.75


def test_order_right_physics_over_wrong_place_over_still():
    ref = ball_clip(falling())
    right = values(ref, ball_clip(falling(vx=8.3, g=2.1)))   # slightly different physics
    wrong = values(ref, ball_clip(falling(x0=60.0, vx=-3.0)))  # the ball goes elsewhere
    frozen = values(ref, still(ref))
    for name in IOUS:
        assert right[name] > wrong[name] > frozen[name] == 0.0, name
        assert wrong[name] < 0.3, (name, wrong[name])
    assert right["masked_mse"] < wrong["masked_mse"]
    assert right["masked_mse"] < frozen["masked_mse"]


def test_a_reference_without_motion_is_nan_with_its_reason(tmp_path):
    ref = still(ball_clip(falling()))
    for gen in (ref.copy(), ball_clip(falling())):
        got = values(ref, gen)
        assert all(math.isnan(got[n]) for n in (*IOUS, "masked_mse")), got
        assert got["mse"] >= 0.0  # whole-frame MSE needs no motion
    inp = MetricInput(scene=_scene(), reference=ref, generated=ref.copy())
    info = M.SpatialIoU().details(inp)
    assert info["reference_moving_fraction"] == 0.0 and "nothing moves" in info["note"]
    # through the scorer: None, never 1.0
    scores, _ = score_scene(_scene(), ref, ref.copy(), [cls() for cls in M.METRICS], None,
                            None, Cache(tmp_path, enabled=False),
                            protocol=ScoringProtocol(aligned=False, paper=False))
    assert scores["spatial_iou"] is None and scores["mse"] == 0.0


def test_a_delay_costs_spatiotemporal_iou_and_the_aligned_pairing_undoes_it():
    ref = ball_clip(falling())
    late = np.concatenate([ref[:1], ref[:1], ref[:-2]])  # everything two frames late
    plain = values(ref, late)
    assert plain["spatial_iou"] > 0.9              # where: right
    assert plain["spatiotemporal_iou"] < 0.5       # when: wrong
    a = align(ref, late, EVERY_FRAME)
    assert a.offset == 2
    assert values(ref, late, a)["spatiotemporal_iou"] == pytest.approx(1.0)


def test_small_noise_and_h264_do_not_move_pixels(tmp_path):
    ref = ball_clip(falling())
    rng = np.random.default_rng(0)
    noisy = np.clip(ref + rng.normal(0, 2.0, ref.shape), 0, 255).astype(np.uint8)
    for gen in (noisy, reencoded(ref, FPS, tmp_path)):
        got = values(ref, gen)
        for name in IOUS:
            assert got[name] > 0.95, (name, got[name])
    still_noisy = np.clip(still(ref) + rng.normal(0, 2.0, ref.shape), 0, 255).astype(np.uint8)
    assert not M.motion_masks(still_noisy, FPS).any()


def test_the_span_is_a_time_not_a_frame_count():
    """The same motion at 5 and at 15 fps moves about the same pixels: 0.2 s is one frame at
    5 fps and three at 15 fps."""
    slow = ball_clip([(60 + 8 * k / 3, 30 + (k / 3) ** 2) for k in range(49)])
    fast = slow[::3]
    m15 = M.motion_masks(slow, 15.0)[::3]
    m5 = M.motion_masks(fast, 5.0)
    assert M.spatiotemporal_iou(m5[1:], m15[1:]) > 0.8
    assert M.MaskParams().step(15.0) == 3 and M.MaskParams().step(5.0) == 1


def test_masks_are_made_once_per_clip_for_all_metrics_and_pairings(monkeypatch):
    ref = ball_clip(falling())
    gen = ball_clip(falling(vx=8.5))
    calls = []
    real = M.motion_masks
    monkeypatch.setattr(M, "motion_masks", lambda *a, **k: calls.append(1) or real(*a, **k))
    inp = MetricInput(scene=_scene(), reference=ref, generated=gen)
    for a in (unaligned(17, 17), align(ref, gen, EVERY_FRAME), align(ref, gen, PAPER)):
        for cls in M.METRICS:
            cls().compute_sequence(inp, a)
            cls().details(inp)
    assert len(calls) == 2


# ------------------------------------------------------------------------------ PHYRE-style scenes
@pytest.fixture(scope="module")
def phyre():
    """Three hand-made PHYRE-style scenes (tests/mini_templates.py) rendered as the 2D
    benchmark renders them (512², 17 frames at 5 fps), each also under 3 % more gravity (nearly
    right physics) and under 30 % of it (wrong physics: the motion starts right, ends elsewhere)."""
    from mini_templates import mini_scenes as make_mini_scenes

    from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d
    from visphy_plugins.physics.box2d import simulate_2d

    def under_gravity(spec: dict, factor: float) -> np.ndarray:
        s = copy.deepcopy(spec)
        s["world"]["gravity_m_s2"][1] *= factor
        return render_clip_2d(s, simulate_2d(s).frame_poses)

    return [(spec["scene_id"], render_clip_2d(spec, rollout.frame_poses),
             under_gravity(spec, 1.03), under_gravity(spec, 0.3))
            for spec, rollout in make_mini_scenes()[:3]]


def test_phyre_scenes_rank_right_physics_over_wrong_place_over_still(phyre, tmp_path):
    for sid, ref, near, slow in phyre:
        scene = _scene(size=512, sid=sid)
        right = values(ref, near, scene=scene)
        wrong_physics = values(ref, slow, scene=scene)
        wrong_place = values(ref, np.roll(ref, 64, axis=2), scene=scene)  # same motion, 64 px off
        frozen = values(ref, still(ref), scene=scene)
        copy_ = values(ref, reencoded(ref, FPS, tmp_path), scene=scene)
        for name in IOUS:
            assert copy_[name] > 0.95, (sid, name, copy_[name])
            assert copy_[name] > right[name] > wrong_physics[name] > frozen[name], (sid, name)
            assert right[name] > wrong_place[name] > frozen[name] == 0.0, (sid, name)
            assert wrong_place[name] < 0.3, (sid, name, wrong_place[name])
        assert right["masked_mse"] < wrong_physics["masked_mse"] < frozen["masked_mse"], sid


# ------------------------------------------------------------------------------ the benchmark
def test_mini_references_against_their_h264_reencode(mini_scenes, tmp_path):
    """The benchmark's own 2D references (exact RGB) against their crf-23 encoding (as the
    published references are): ≈ 1; a frozen first frame: 0; three pixels off: high, < 1."""
    for scene in mini_scenes:
        ref = scene.reference_frames()
        got = values(ref, reencoded(ref, scene.clip.fps, tmp_path), scene=scene)
        for name in IOUS:
            assert got[name] > 0.97, (scene.scene_id, name, got[name])
        assert [values(ref, still(ref), scene=scene)[n] for n in IOUS] == [0.0] * 3
        shifted = values(ref, np.roll(ref, 3, axis=2), scene=scene)
        for name in IOUS:
            assert 0.6 < shifted[name] < 1.0, (scene.scene_id, name, shifted[name])


def test_a_run_on_the_mini_split_writes_every_column(visphy_home):
    """The static baseline (a held first frame) through the CLI: every column under the three
    pairings, each IoU 0 on every scene, masked MSE and MSE positive."""
    names = ",".join(NAMES)
    run_cli("dataset=mini", "model=static", f"metrics.names=[{names}]", "tracking=none",
            "run.progress=false", "metrics.spec_track=false", "metrics.variance_norm=false",
            home=visphy_home)
    run_dir = max((visphy_home / "runs").iterdir(), key=lambda p: p.stat().st_mtime)
    summary = json.loads((run_dir / "summary.json").read_text())
    for name in NAMES:
        for col in (name, f"{name}.aligned", f"paper.{name}"):
            m = summary["metrics"][col]
            assert m["unavailable"] is None and m["n_model_success"] == summary["n_scenes"], col
            if name in IOUS:
                assert m["mean_model_success"] == 0.0, col
            else:
                assert m["mean_model_success"] > 0.0, col
    details = json.loads(next(run_dir.glob("scenes/*/metric_details.json")).read_text())
    assert details["motion_masks"]["reference_moving_fraction"] > 0.0
    assert details["motion_masks"]["generated_moving_fraction"] == 0.0


# ------------------------------------------------------------------------------ 3D
@pytest.fixture(scope="module")
def reference_3d(mini_root, tmp_path_factory):
    """One 3D scene of the generated benchmark, rendered and encoded (crf 23) as a full build
    writes it, decoded as a run reads it."""
    import shutil

    from visphy_core.api.assets import assets_installed
    from visphy_core.sandbox.browser import BrowserPool
    from visphy_plugins.datasets.visphybench.build import (
        dataset_root,
        load_or_build_catalogue,
        write_scene,
    )
    from visphy_plugins.datasets.visphybench.loader import load_generated

    if not assets_installed():
        pytest.skip("browser engine libraries not installed (`python -m visphy_core setup`)")
    root = dataset_root(tmp_path_factory.mktemp("mm3d"))
    root.mkdir(parents=True)
    shutil.copy(mini_root / "catalogue.json", root / "catalogue.json")
    catalogue = load_or_build_catalogue(root, seed=0, progress=False)
    entry = next(e for e in catalogue.entries if e.spec["scene_id"] == "vpb3-s0-3d-t006-v01")
    with BrowserPool(untrusted=False) as pool:
        meta = write_scene(entry, root, pool)
    (root / "metadata.jsonl").write_text(json.dumps(meta) + "\n")
    (scene,) = load_generated(root)
    return scene, scene.reference_frames()


@pytest.mark.browser
def test_3d_reference_against_its_reencode_a_shift_and_a_still_clip(reference_3d, tmp_path):
    scene, ref = reference_3d
    assert scene.clip.fps == 15.0 and len(ref) == 75
    copy_ = values(ref, reencoded(ref, scene.clip.fps, tmp_path), scene=scene)
    shifted = values(ref, np.roll(ref, 3, axis=2), scene=scene)
    frozen = values(ref, still(ref), scene=scene)
    for name in IOUS:
        assert copy_[name] > 0.95, (name, copy_[name])
        assert 0.6 < shifted[name] < copy_[name], (name, shifted[name])
        assert frozen[name] == 0.0, name
    assert copy_["masked_mse"] < shifted["masked_mse"] < frozen["masked_mse"]
