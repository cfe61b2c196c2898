"""Object-track metrics (plugins/metrics/tracks.py): colour segmentation against the ground
truth, zero on identical clips, monotone growth with perturbed physics, penalties for frozen and
recoloured bodies, the event detectors on synthetic motion, and a 3D clip (also in a paler
palette). Drawing styles (paler, tinted, outlined, shaded…): test_metrics_tracks_colour.py."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from mini_templates import SCENES
from mini_templates import mini_scenes as make_mini_scenes
from scipy.stats import spearmanr

from visphy_core.api.metrics import LOWER, SEQUENCE, MetricInput
from visphy_core.api.scene import Scene
from visphy_core.infra.video import ClipInfo, decode_video, encode_video
from visphy_core.scoring.alignment import PAPER, align, unaligned
from visphy_core.scoring.score import ScoringProtocol, alignments
from visphy_plugins.datasets.visphybench.detection import detection_from_spec
from visphy_plugins.datasets.visphybench.detection3d import detection_from_spec_3d
from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d, render_frame_2d
from visphy_plugins.metrics import track_segments
from visphy_plugins.metrics import tracks as T
from visphy_plugins.physics.box2d import simulate_2d

SCENE_3D = "vpb3-s0-3d-t003-v02"  # a 3D scene of the generated benchmark (template 3)
NAMES = T.NAMES
CLIP_2D = ClipInfo(fps=5.0, n_frames=17, width=512, height=512)
DIAG = math.hypot(512, 512)


# ------------------------------------------------------------------------------ helpers
def make_scene(spec: dict, root: Path, clip: ClipInfo = CLIP_2D, video: Path | None = None,
               with_spec: bool = True, with_detection: bool = True) -> Scene:
    """A `Scene` backed by files, as the loaders build it."""
    root.mkdir(parents=True, exist_ok=True)
    sid = spec["scene_id"]
    spec_path = det_path = None
    if with_spec:
        spec_path = root / f"{sid}.json"
        spec_path.write_text(json.dumps(spec))
    if with_detection:
        det_path = root / f"{sid}_frame_01.json"
        det = detection_from_spec(spec) if spec["dim"] == "2d" else detection_from_spec_3d(spec)
        det_path.write_text(json.dumps(det))
    return Scene(scene_id=sid, dim=spec["dim"], clip=clip,
                 video_path=video or root / f"{sid}.mp4", detection_path=det_path,
                 spec_path=spec_path)


def clean_clip(spec: dict) -> np.ndarray:
    return render_clip_2d(spec, simulate_2d(spec).frame_poses)


def values(scene, ref, gen, alignment=None) -> dict[str, float]:
    inp = MetricInput(scene=scene, reference=ref, generated=gen)
    a = alignment if alignment is not None else unaligned(len(ref), len(gen))
    return {m.name: m.compute_sequence(inp, a) for m in (cls() for cls in T.METRICS)}


def perturbed(spec: dict, kind: str, step: int) -> dict:
    """``spec`` with one physical parameter moved ``step`` (0..5) geometric steps away."""
    s = copy.deepcopy(spec)
    red = next(b for b in s["bodies"] if b["id"] == "red_ball")
    if kind == "speed":
        red["velocity"]["vx_px_s"] += (0, 2, 4, 8, 16, 32)[step]
    elif kind == "gravity":
        s["world"]["gravity_m_s2"][1] *= (1, 1.03, 1.06, 1.12, 1.24, 1.48)[step]
    elif kind == "restitution":
        d = (0, 0.05, 0.1, 0.2, 0.35, 0.6)[step]
        s["contacts"]["default"]["restitution"] = min(
            1.0, s["contacts"]["default"]["restitution"] + d)
        for pair in s["contacts"]["pairs"]:
            pair["restitution"] = min(1.0, pair["restitution"] + d)
    return s


# ------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    """The five hand-made PHYRE-style scenes: spec, rollout, clean clip and a file-backed
    Scene; the first three also with their H.264 reference (encoded and decoded as the
    benchmark writes it)."""
    root = tmp_path_factory.mktemp("tracks")
    out = []
    for i, (spec, rollout) in enumerate(make_mini_scenes()):
        clip = render_clip_2d(spec, rollout.frame_poses)
        video = root / f"{spec['scene_id']}.mp4"
        decoded = None
        if i < 3:
            encode_video(clip, video, 5.0)
            decoded, _ = decode_video(video)
        out.append({"spec": spec, "rollout": rollout, "clip": clip, "decoded": decoded,
                    "scene": make_scene(spec, root, video=video)})
    return out


# ------------------------------------------------------------------------------ contract
def test_five_sequence_metrics_registered_with_their_contract():
    got = []
    T.visphy_register_metrics(got.append)
    assert [m.name for m in got] == list(NAMES)
    for m in got:
        assert (m.kind, m.direction, m.family) == (SEQUENCE, LOWER, "physics")
        assert m.needs == ("frames", "scene_spec") and m.weights is None
        assert m.unavailable_reason() is None


def test_palette_tracks_distinct_dynamic_colours_and_skips_shared_ones(mini, tmp_path):
    spec = copy.deepcopy(mini[0]["spec"])  # red ball, black bar, purple box, gray ball
    pal = T.scene_palette(mini[0]["scene"])
    assert pal.mode == "flat" and pal.ids == ("red_ball", "gray_ball") and not pal.skipped
    twin = copy.deepcopy(next(b for b in spec["bodies"] if b["id"] == "gray_ball"))
    twin["id"], twin["pose"]["x_px"] = "gray_ball_2", 300.0
    spec["bodies"].append(twin)
    pal = T.scene_palette(make_scene(spec, tmp_path))
    assert pal.ids == ("red_ball",)
    assert dict(pal.skipped) == {"gray_ball": "shares its colour with gray_ball_2",
                                 "gray_ball_2": "shares its colour with gray_ball"}
    assert (185, 202, 210) in pal.others  # its pixels are nobody else's
    # no spec: the detection, PHYRE's convention (black and purple are static)
    pal = T.scene_palette(make_scene(mini[0]["spec"], tmp_path / "det", with_spec=False))
    assert pal.ids == ("red_ball", "gray_ball")
    # neither: no palette, every metric NaN
    bare = make_scene(mini[0]["spec"], tmp_path / "bare", with_spec=False,
                      with_detection=False)
    assert T.scene_palette(bare) is None
    clip = mini[0]["clip"]
    assert all(math.isnan(v) for v in values(bare, clip, clip).values())


# -------------------------------------------------------------------------- segmentation
def test_segmentation_recovers_ground_truth_positions_on_h264_references(mini):
    """On the encoded reference every tracked body's centroid is within 1.5 px of the centroid
    of its visible pixels in the exact render, and a free ball's within 1.5 px of its pose."""
    checked = 0
    for m in mini[:3]:
        spec, scene = m["spec"], m["scene"]
        pal = T.scene_palette(scene)
        tracks = T.segment(m["decoded"], pal)
        ids = [b["id"] for b in spec["bodies"]]
        for b, bid in enumerate(pal.ids):
            body = spec["bodies"][ids.index(bid)]
            visible = (m["clip"] == np.array(body["color_rgb"], np.uint8)).all(-1)
            for k in range(len(m["clip"])):
                if visible[k].sum() < 50:
                    continue
                ys, xs = np.nonzero(visible[k])
                want = np.array([xs.mean() + 0.5, ys.mean() + 0.5])
                err = np.hypot(*(tracks.centroid[k, b] - want))
                assert err <= 1.5, (spec["scene_id"], bid, k, err)
                assert abs(tracks.area[k, b] - visible[k].sum()) <= 0.15 * visible[k].sum()
                if body["shape"]["type"] == "circle":
                    r = body["shape"]["radius_px"]
                    if visible[k].sum() >= 0.97 * math.pi * r * r:  # not hidden nor cut
                        x, y = m["rollout"].frame_poses[k, ids.index(bid), :2]
                        assert np.hypot(*(tracks.centroid[k, b] - (x, 512 - y))) <= 1.5
                checked += 1
    assert checked >= 80


def test_identical_clips_score_zero_under_every_pairing(mini):
    m = mini[1]
    ref = m["decoded"]
    inp = MetricInput(scene=m["scene"], reference=ref, generated=ref.copy())
    for view, a in alignments(ref, inp.generated, ScoringProtocol()).items():
        got = {cls.name: cls().compute_sequence(inp, a) for cls in T.METRICS}
        assert got == dict.fromkeys(NAMES, 0.0), (view, got)


def test_segmentation_runs_once_per_clip(mini, monkeypatch):
    # the tracks' cost per scene is benchmarks/bench_metrics.py's (track_* per 2D scene)
    m = mini[0]
    ref, gen = m["decoded"], clean_clip(perturbed(m["spec"], "speed", 2))
    calls = []
    real = T.segment
    monkeypatch.setattr(track_segments, "segment",
                        lambda *a, **k: calls.append(1) or real(*a, **k))
    inp = MetricInput(scene=m["scene"], reference=ref, generated=gen)
    views = alignments(ref, gen, ScoringProtocol())
    T.segment(ref, T.scene_palette(m["scene"]))  # warm the colour table
    calls.clear()
    for a in views.values():
        for cls in T.METRICS:
            cls().compute_sequence(inp, a)
    assert len(calls) == 2  # reference and generated, shared by 5 metrics × 3 pairings
    assert inp.extra["tracks"]["value"]["tracked"] == ["red_ball", "gray_ball"]


# ------------------------------------------------------------------------------ validity
def _assert_monotone(spec: dict, kind: str, ref: np.ndarray, scene) -> None:
    rows = [values(scene, ref, clean_clip(perturbed(spec, kind, k))) for k in range(6)]
    for name in ("track_pos_err", "track_vel_err"):
        xs = [r[name] for r in rows]
        assert xs[0] == 0.0
        rho = spearmanr(range(5), xs[1:]).statistic
        assert rho >= 0.9 - 1e-9 and xs[5] > xs[1] > 0, (spec["scene_id"], kind, name, xs)


@pytest.mark.parametrize("index", [0, 1, 3])
def test_errors_grow_with_the_initial_speed(mini, index):
    m = mini[index]
    _assert_monotone(m["spec"], "speed", m["clip"], m["scene"])


@pytest.mark.parametrize("index", [0, 1, 2, 3, 4])
def test_errors_grow_with_gravity(mini, index):
    m = mini[index]
    _assert_monotone(m["spec"], "gravity", m["clip"], m["scene"])


def test_errors_grow_with_restitution_where_it_is_identifiable(mini):
    chosen = [m for m in mini if m["spec"]["ground_truth"]["identifiable"]["restitution"]]
    assert len(chosen) >= 2
    for m in chosen:
        _assert_monotone(m["spec"], "restitution", m["clip"], m["scene"])


def test_a_frozen_clip_scores_worse_than_a_slightly_wrong_simulation(mini):
    for m in mini[:3]:
        ref = m["clip"]
        frozen = np.repeat(ref[:1], len(ref), axis=0)
        slight = clean_clip(perturbed(m["spec"], "speed", 1))
        got_frozen, got_slight = (values(m["scene"], ref, g) for g in (frozen, slight))
        assert got_frozen["track_pos_err"] > 3 * got_slight["track_pos_err"] > 0
        assert got_frozen["track_vel_err"] > got_slight["track_vel_err"]


def test_a_body_drawn_in_another_hue_is_not_found_and_costs_the_bounded_penalty(mini):
    m = mini[0]
    ref = m["clip"]
    gen = ref.copy()
    red = (gen == np.array([243, 79, 70], np.uint8)).all(-1)
    gen[red] = (255, 0, 255)  # the model drew the red ball magenta: ≈ 60° of hue away
    inp = MetricInput(scene=m["scene"], reference=ref, generated=gen)
    got = T.track_values(inp, unaligned(len(ref), len(gen)))
    st = inp.extra["tracks"]["value"]
    assert not st["gen_present"][:, 0].any() and st["gen_present"][:, 1].all()
    pr = st["ref_present"]
    n_red, n_gray = pr[:, 0].sum(), pr[:, 1].sum()
    penalty = T.MISSING_DIAG_FRACTION * DIAG  # D / 4, not the whole diagonal
    assert got["track_pos_err"] == pytest.approx(penalty * n_red / (n_red + n_gray))
    i_red, i_gray = (pr[1:] & pr[:-1]).sum(axis=0)
    # each interval of the red ball costs at least P / T (T = 16 / 5 s), the gray ball's nothing
    assert got["track_vel_err"] >= penalty / (16 / 5.0) * i_red / (i_red + i_gray)


def test_aligned_pairing_undoes_a_delay_and_events_use_the_reference_clock(mini):
    m = mini[3]
    ref = m["clip"]
    late = np.concatenate([np.repeat(ref[:1], 2, axis=0), ref[:-2]])
    plain = values(m["scene"], ref, late)
    a = align(ref, late)
    assert a.offset == 2
    shifted = values(m["scene"], ref, late, a)
    assert plain["track_pos_err"] > 10
    assert shifted == dict.fromkeys(NAMES, 0.0)
    paper = values(m["scene"], ref, late, align(ref, late, PAPER))
    assert paper["track_pos_err"] < plain["track_pos_err"]


def test_no_tracked_body_in_the_reference_is_nan(mini):
    m = mini[0]
    blank = np.full_like(m["clip"], 255)
    got = values(m["scene"], blank, m["clip"])
    assert all(math.isnan(v) for v in got.values())
    got = values(m["scene"], m["clip"], blank)  # all lost in the generated clip: D / 4
    assert got["track_pos_err"] == pytest.approx(DIAG / 4)


# ------------------------------------------------------------------------------- events
def _ball_spec(path_xy) -> tuple[dict, np.ndarray]:
    """A one-ball scene and its clip along the given image-space path (x, y down)."""
    spec = SCENES[-1]()  # the corner drop: a red ball of radius 20 px
    spec["bodies"] = [b for b in spec["bodies"] if b["id"] == "red_ball"]
    frames = np.stack([render_frame_2d(spec, np.array([[x, 512 - y, 0.0]]))
                       for x, y in path_xy])
    return spec, frames


def _event_values(path_a, path_b, tmp_path) -> tuple[dict, dict]:
    spec, ref = _ball_spec(path_a)
    _, gen = _ball_spec(path_b)
    scene = make_scene(spec, tmp_path)
    inp = MetricInput(scene=scene, reference=ref, generated=gen)
    a = unaligned(len(ref), len(gen))
    return T.track_values(inp, a), T.track_events(inp, a)


def test_exit_event_time_difference(tmp_path):
    """A ball (radius 20 px) rolling right at 40 px/frame leaves the frame; the other at 50
    px/frame. Each has wholly left when its centre is 20 px past the edge (x = 532): frame
    10.8 and 8.64, inside the interval after the last frame it is seen in (10 and 8)."""
    a = [(100 + 40 * k, 300.0) for k in range(17)]    # last seen at x = 500 (frame 10)
    b = [(100 + 50 * k, 300.0) for k in range(17)]    # last seen at x = 500 (frame 8)
    got, ev = _event_values(a, b, tmp_path)
    assert ev["ref"]["exit"] == [pytest.approx(10.8 / 5, abs=0.01)]
    assert ev["gen"]["exit"] == [pytest.approx(8.64 / 5, abs=0.01)]
    assert got["event_exit_err"] == pytest.approx(2.16 / 5, abs=0.02)
    got, _ = _event_values(a, [(100.0, 300.0)] * 17, tmp_path)  # never leaves: one-sided
    assert got["event_exit_err"] == pytest.approx(16 / 5)


def test_rest_event_time_difference(tmp_path):
    def decelerating(stop: int):
        v0 = 60.0
        xs = [100 + v0 * min(k, stop) - v0 / (2 * stop) * min(k, stop) ** 2 for k in range(17)]
        return [(x, 400.0) for x in xs]

    got, ev = _event_values(decelerating(6), decelerating(9), tmp_path)
    ref_rest, gen_rest = ev["ref"]["rest"][0], ev["gen"]["rest"][0]
    assert ref_rest == pytest.approx(6 / 5, abs=0.21) and gen_rest == pytest.approx(9 / 5, abs=0.21)
    assert got["event_rest_err"] == pytest.approx(gen_rest - ref_rest)
    got, _ = _event_values(decelerating(6), [(100 + 30.0 * k, 400.0) for k in range(17)],
                           tmp_path)  # the other never stops
    assert got["event_rest_err"] == pytest.approx(16 / 5)


def test_contact_event_time_difference(tmp_path):
    """Free fall (constant acceleration), then a bounce off the floor at frame 7 or 10."""
    def bounce(k_hit: int):
        g = 6.0  # px/frame^2
        floor = 50 + 0.5 * g * k_hit ** 2
        out = []
        for k in range(17):
            y = 50 + 0.5 * g * k ** 2
            if k > k_hit:  # reflected with restitution 0.5
                v = 0.5 * g * k_hit
                y = floor - (v * (k - k_hit) - 0.5 * g * (k - k_hit) ** 2)
                y = min(y, floor)
            out.append((250.0, y))
        return out

    got, ev = _event_values(bounce(7), bounce(10), tmp_path)
    ref_t, gen_t = ev["ref"]["contact"][0], ev["gen"]["contact"][0]
    assert ref_t == pytest.approx(7 / 5, abs=0.03) and gen_t == pytest.approx(10 / 5, abs=0.03)
    assert got["event_contact_err"] == pytest.approx(gen_t - ref_t)
    assert got["event_contact_err"] == pytest.approx(3 / 5, abs=0.03)
    # parabola without a bounce in the other clip: one-sided
    free = [(250.0, 50 + 0.5 * 1.0 * k ** 2) for k in range(17)]
    got, ev = _event_values(bounce(7), free, tmp_path)
    assert ev["gen"]["contact"] == [None] and got["event_contact_err"] == pytest.approx(16 / 5)


def test_contact_detection_matches_the_simulated_first_contacts(mini):
    """The red ball's first collision in each mini scene, timed from its track, lies within
    0.12 s (0.6 of a frame interval) of Box2D's first contact event (clip time)."""
    for m in mini:
        spec = m["spec"]
        w = spec["world"]
        first = min(e["step"] for e in spec["ground_truth"]["events"]
                    if "red_ball" in (e["a"], e["b"]))
        t_gt = (first - w["first_frame_after_steps"]) / w["steps_per_frame"] / w["video_fps"]
        ev = T.track_events(MetricInput(scene=m["scene"], reference=m["clip"],
                                        generated=m["clip"]), unaligned(17, 17))
        t_det = ev["ref"]["contact"][0]
        assert t_det is not None and abs(t_det - t_gt) <= 0.12, (spec["scene_id"], t_det, t_gt)


# ------------------------------------------------------------- sub-frame event estimators
FPS = 5.0


def _bounce(t_hit: float, n: int = 17, g: float = 20.0, e: float = 0.6) -> np.ndarray:
    """A ball thrown up and right (px, y down, frames as time unit), bouncing off a floor at
    ``t_hit`` with restitution ``e``: two parabolas with the same gravity meeting there."""
    t = np.arange(n, dtype=float)
    vy0, vx = -10.0, 12.0
    y_hit, v_hit = 100 + vy0 * t_hit + 0.5 * g * t_hit ** 2, vy0 + g * t_hit
    d = t - t_hit
    y = np.where(t <= t_hit, 100 + vy0 * t + 0.5 * g * t ** 2,
                 y_hit - e * v_hit * d + 0.5 * g * d ** 2)
    return np.stack([100 + vx * t, y], axis=-1)


def _ramp_landing(t_hit: float, n: int = 17, g: float = 20.0) -> np.ndarray:
    """A ball in free fall landing at ``t_hit`` on a 30° ramp and sliding down it: the velocity
    jumps (its normal part is lost, 20% of the rest too) and the acceleration changes from g
    to g·sin 30° along the ramp."""
    t = np.arange(n, dtype=float)
    d = t - t_hit
    fall = np.stack([100 + 8 * t, 50 + 0.5 * g * t ** 2], axis=-1)
    at = np.array([100 + 8 * t_hit, 50 + 0.5 * g * t_hit ** 2])
    along = np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    speed = 0.8 * float(np.array([8.0, g * t_hit]) @ along)
    slide = at + np.outer(speed * d + 0.25 * g * d ** 2, along)
    return np.where((t <= t_hit)[:, None], fall, slide)


def _contact(track: np.ndarray, noise: float = 0.0, seed: int = 0, fps: float = FPS,
             offset: int = 0) -> float | None:
    """`T.contact_times` of one body on a clip's own frames shifted by ``offset`` against the
    pairs' clock (frame k of the track is paired with reference frame k)."""
    rng = np.random.default_rng(seed)
    c = (track + rng.normal(0.0, noise, track.shape))[:, None, :]
    n = len(track)
    frames = np.arange(n) + offset
    tau = np.arange(n) / fps
    return T.contact_times(c, np.ones((n, 1), bool), np.full((n, 1), 1250.0), frames, fps,
                           tau, 4.34)[0]


@pytest.mark.parametrize("t_hit", [1.3, 1.7, 2.05, 2.5, 2.95, 4.37, 6.1, 6.5, 9.73, 12.4])
def test_contact_time_is_exact_on_a_bounce_at_a_fractional_frame(t_hit):
    got = _contact(_bounce(t_hit))
    assert got == pytest.approx(t_hit / FPS, abs=1e-3)
    k = math.floor(t_hit)
    assert k / FPS <= got <= (k + 1) / FPS  # inside the interval of the kink


@pytest.mark.parametrize("t_hit", [3.5, 4.37, 6.1, 6.9, 9.73])
def test_contact_time_is_exact_when_the_acceleration_changes_too(t_hit):
    """Different accelerations before and after (landing on a ramp): exact once four frames
    either side are seen."""
    assert _contact(_ramp_landing(t_hit)) == pytest.approx(t_hit / FPS, abs=1e-3)


@pytest.mark.parametrize("t_hit", [2.05, 2.95, 4.37, 6.5, 9.73])
def test_contact_time_under_centroid_noise(t_hit):
    """0.3 px of centroid noise (the H.264 references' mean error): within 0.02 s at 5 fps."""
    for seed in range(8):
        assert _contact(_bounce(t_hit), 0.3, seed) == pytest.approx(t_hit / FPS, abs=0.02)
        if t_hit >= 3.5:
            assert _contact(_ramp_landing(t_hit), 0.3, seed) == pytest.approx(t_hit / FPS,
                                                                               abs=0.03)


def test_contact_time_moves_continuously_with_the_impact():
    """Sweeping the impact across frame boundaries moves the time with it, never in steps."""
    hits = np.linspace(3.6, 6.4, 57)
    got = np.array([_contact(_bounce(t)) for t in hits])
    assert np.abs(got - hits / FPS).max() < 1e-3
    assert (np.diff(got) > 0).all()


def test_contact_time_on_another_frame_rate_and_the_pairs_clock():
    """15 fps (the 3D clips), and a generated clip whose frames are paired 3 frames late: the
    time is read on the pairs' clock."""
    assert _contact(_bounce(20.37, n=75, g=2.2), fps=15.0) == pytest.approx(20.37 / 15, abs=1e-3)
    assert _contact(_bounce(6.37), offset=3) == pytest.approx(6.37 / FPS, abs=1e-3)


def test_kink_time_finds_where_two_parabolas_meet():
    t = np.arange(9) * 0.2
    at = 0.2 * 4.3
    pre = np.stack([3 + 40 * t, 7 - 5 * t + 30 * t ** 2], axis=-1)
    post_at = np.array([3 + 40 * at, 7 - 5 * at + 30 * at ** 2])
    d = t - at
    post = post_at + np.stack([-25 * d + 4 * d ** 2, 18 * d - 11 * d ** 2], axis=-1)
    y = np.where((t <= at)[:, None], pre, post)
    got, cost = T.kink_time(t, y, 5)  # five points before the change: it is in (0.8, 1.0)
    assert got == pytest.approx(at, abs=1e-4) and cost < 1e-6
    got, cost = T.kink_time(t, y, 4)  # the wrong interval: a poor fit at its end
    assert got == pytest.approx(0.8) and cost > 1.0


def _decelerating(stop: float, v0: float = 10.0, n: int = 17) -> np.ndarray:
    """A body sliding right from x = 100 at ``v0`` px/frame, braking uniformly to rest at
    frame ``stop``."""
    t = np.minimum(np.arange(n, dtype=float), stop)
    x = 100 + v0 * t - v0 / (2 * stop) * t ** 2
    return np.stack([x, np.full(n, 400.0)], axis=-1)


def _rest(track: np.ndarray, noise: float = 0.0, seed: int = 0) -> float | None:
    rng = np.random.default_rng(seed)
    c = (track + rng.normal(0.0, noise, track.shape))[:, None, :]
    n = len(track)
    return T.rest_times(c, np.ones((n, 1), bool), np.arange(n), FPS, np.arange(n) / FPS,
                        T.REST_PX_PER_FRAME * FPS)[0]


@pytest.mark.parametrize("stop", [11.3, 12.5, 13.75, 14.4])
def test_rest_time_is_interpolated_between_frames(stop):
    """The speed (10 px/frame braking to 0 at ``stop``) falls below 1 px/frame at
    0.9·stop. Exact while the speed is linear across the two intervals around it (the body
    still slides through the second), and within half a frame when it stops inside it."""
    got = _rest(_decelerating(stop))
    cross = 0.9 * stop
    mid = math.floor(cross - 0.5) + 0.5  # the middle of the interval before the crossing
    if mid + 2 <= stop:
        assert got == pytest.approx(cross / FPS, abs=1e-3)
    assert abs(got - cross / FPS) <= 0.5 / FPS
    assert _rest(_decelerating(stop), 0.05, 1) == pytest.approx(got, abs=0.05)


def test_rest_time_moves_continuously_with_the_stop():
    stops = np.linspace(8.0, 14.0, 61)
    got = np.array([_rest(_decelerating(s)) for s in stops])
    assert (np.diff(got) > 0).all() and np.abs(np.diff(got)).max() < 0.05


def _leaving(n: int = 17, radius: float = 20.0, size: int = 512):
    """A disc of ``radius`` px falling out through the bottom edge: y = 100 + 5 t + 3 t²
    (frames). Its visible area shrinks as the border cuts it; it is missing once less than
    3% of it is visible."""
    t = np.arange(n, dtype=float)
    y = 100 + 5 * t + 3 * t ** 2
    c = np.stack([np.full(n, 250.0), y], axis=-1)
    full = math.pi * radius ** 2
    depth = np.clip(size - (y - radius), 0, 2 * radius)  # visible height of the disc
    h = depth - radius  # signed distance from the centre to the chord
    seg = radius ** 2 * np.arccos(np.clip(-h / radius, -1, 1)) \
        + h * np.sqrt(np.clip(radius ** 2 - h ** 2, 0, None))
    area = np.where(depth >= 2 * radius, full, seg)
    present = area >= 0.03 * full
    # the centroid of what is visible: pulled inside the frame while the border cuts it
    cut = present & (area < full)
    c[cut, 1] = np.minimum(c[cut, 1], size - depth[cut] / 2)
    exit_t = (-5 + math.sqrt(25 + 12 * (size + radius - 100))) / 6  # y = size + radius
    return c, present, area, exit_t


def test_exit_time_is_where_the_path_has_wholly_left():
    c, present, area, exit_t = _leaving()
    n = len(c)
    c = np.where(present[:, None], c, np.nan)
    got = T.exit_times(c[:, None], present[:, None], area[:, None], np.array([area.max()]),
                       np.arange(n) / FPS, (512, 512), np.arange(n), FPS)[0]
    last = int(np.flatnonzero(present)[-1])
    assert last < exit_t < last + 1
    assert got == pytest.approx(exit_t / FPS, abs=1e-3)
    # without frames and fps, the pairs' clock is the clip's own
    same = T.exit_times(c[:, None], present[:, None], area[:, None], np.array([area.max()]),
                        np.arange(n) / FPS, (512, 512))[0]
    assert same == pytest.approx(got)


# ----------------------------------------------------------------------------------- 3D
def _check_3d(scene, frames: np.ndarray, poses: np.ndarray | None) -> None:
    from visphy_plugins.datasets.visphybench.detection3d import project_points

    pal = T.scene_palette(scene)
    assert pal.mode == "shaded" and pal.ids and "red_ball" in pal.ids
    tracks = T.segment(frames, pal)
    inp = MetricInput(scene=scene, reference=frames, generated=frames.copy())
    st = T.scene_tracks(inp)
    found = st["ref_present"].mean(axis=0)
    assert found.min() >= 0.8, dict(zip(pal.ids, found))
    if poses is not None:
        ids = [b["id"] for b in scene.spec["bodies"]]
        want = project_points(scene.spec, poses[:len(frames), ids.index("red_ball"), :3])
        err = np.hypot(*(tracks.centroid[:, pal.ids.index("red_ball")] - want).T)
        assert np.nanmax(err) <= 2.0, err
    got = T.track_values(inp, unaligned(len(frames), len(frames)))
    assert got == dict.fromkeys(NAMES, 0.0)
    moved = np.roll(frames, 3, axis=2)  # everything 3 px to the right
    got = values(scene, frames, moved)
    assert 2.0 <= got["track_pos_err"] <= 4.0


@pytest.mark.browser
def test_3d_rendered_clip_segments_every_dynamic_body(tmp_path):
    import shutil

    from visphy_core.api.assets import assets_installed

    if shutil.which("node") is None or not assets_installed():
        pytest.skip("Node.js or the browser engine libraries are missing")
    from visphy_core.sandbox.browser import BrowserPool
    from visphy_core.spec.spec3d import validate_spec_3d
    from visphy_plugins.datasets.visphybench.render3d import render_clip_3d
    from visphy_plugins.datasets.visphybench.screening3d import validity_problems_3d
    from visphy_plugins.datasets.visphybench.templates_3d import TEMPLATES_3D
    from visphy_plugins.physics.cannon import simulate_3d

    template = next(t for t in TEMPLATES_3D if t.template_id == 10)  # ball, box, ball
    for k in range(4):
        spec = template.make(np.random.default_rng(template.template_id * 100 + k), 0)
        validate_spec_3d(spec)
        rollout = simulate_3d(spec)
        if not validity_problems_3d(spec, rollout):
            break
    n = 40
    pale = copy.deepcopy(spec)  # the palette 50% paler, as models draw it
    for body in pale["bodies"]:
        body["color_rgb"] = [round((c + 255) / 2) for c in body["color_rgb"]]
    with BrowserPool() as pool:
        clip = render_clip_3d(spec, rollout.frame_poses[:n], pool)
        pale_clip = render_clip_3d(pale, rollout.frame_poses[:n], pool)
    encode_video(clip, tmp_path / "c.mp4", 15.0)
    frames, _ = decode_video(tmp_path / "c.mp4")
    scene = make_scene(spec, tmp_path, clip=ClipInfo(15.0, n, 512, 512))
    _check_3d(scene, frames, rollout.frame_poses)
    # three.js shading of a paler palette: found by the colour-tolerant association, within
    # 0.5 px of the exact render (itself 0.5-0.7 px from its H.264 encoding)
    exact = values(scene, frames, clip)
    got = values(scene, frames, pale_clip)
    assert T.segment(pale_clip, T.scene_palette(scene)).area.max() == 0  # beyond the palette
    assert got["track_pos_err"] <= exact["track_pos_err"] + 0.5, (got, exact)
    assert got["track_vel_err"] <= exact["track_vel_err"] + 5.0, (got, exact)


@pytest.fixture(scope="module")
def built_3d(mini_root, tmp_path_factory) -> Path:
    """A dataset root holding one 3D scene of the generated benchmark (`SCENE_3D`), written by
    the builder as a full build writes it (the `mini` split is 2D only): the session build's
    catalogue, the scene re-simulated against its digest and rendered, and its metadata."""
    import shutil

    from visphy_core.api.assets import assets_installed
    from visphy_core.sandbox.browser import BrowserPool
    from visphy_plugins.datasets.visphybench.build import (
        dataset_root,
        load_or_build_catalogue,
        write_scene,
    )

    if not assets_installed():
        pytest.skip("browser engine libraries not installed (`python -m visphy_core setup`)")
    root = dataset_root(tmp_path_factory.mktemp("data3d"))
    root.mkdir(parents=True)
    shutil.copy(mini_root / "catalogue.json", root / "catalogue.json")
    catalogue = load_or_build_catalogue(root, seed=0, progress=False)
    entry = next(e for e in catalogue.entries if e.spec["scene_id"] == SCENE_3D)
    with BrowserPool(untrusted=False) as pool:  # visphy's own reference page, as in a build
        meta = write_scene(entry, root, pool)
    (root / "metadata.jsonl").write_text(json.dumps(meta) + "\n")
    return root


@pytest.mark.browser
def test_3d_dataset_clip_segments_every_dynamic_body(built_3d):
    """A 3D reference of the built benchmark, loaded as a run loads it."""
    from visphy_plugins.datasets.visphybench.loader import load_generated

    (scene,) = load_generated(built_3d)
    assert scene.scene_id == SCENE_3D and scene.dim == "3d"
    _check_3d(scene, scene.reference_frames(), scene.trajectory["frame_poses"])
