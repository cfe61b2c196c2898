"""The run report's plots from given data (visphy_core.report.plots, scene_plots, frame_data):
what each plot draws, its scale, and the line that replaces a plot that cannot be drawn.
The plots of real runs, in Chromium, are tested in tests/test_report.py."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from visphy_core.infra.video import encode_video
from visphy_core.report.frame_data import FrameData, compute
from visphy_core.report.plots import family_bars, headline_plot
from visphy_core.report.scene_plots import psnr_curve, scene_plots, track_overlay

RED, BLUE, BLACK = (243, 79, 70), (33, 150, 243), (0, 0, 0)
SPEC = {"dim": "2d", "render": {"background_rgb": [255, 255, 255]},
        "bodies": [{"id": "red_ball", "dynamic": True, "color_rgb": list(RED)},
                   {"id": "blue_ball", "dynamic": True, "color_rgb": list(BLUE)},
                   {"id": "bar", "dynamic": False, "color_rgb": list(BLACK)}]}


def _attrs(html: str, tag: str, cls: str) -> list[dict[str, str]]:
    """The attributes of every ``<tag class="cls" …>`` in ``html``."""
    out = []
    for match in re.finditer(rf'<{tag} class="{cls}"([^>]*)>', html):
        out.append(dict(re.findall(r'([\w-]+)="([^"]*)"', match.group(1))))
    return out


def _clip(path: Path, centres: list[tuple[float, float] | None], size=(96, 128)) -> Path:
    """A white clip with a red disc (radius 8) at each frame's centre (x, y), a blue disc
    resting at (20, 20) and a black bar."""
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    frames = []
    for c in centres:
        f = np.full((h, w, 3), 255, np.uint8)
        f[(xx - 20) ** 2 + (yy - 20) ** 2 <= 64] = BLUE
        f[h - 10:h - 4, 10:w - 10] = BLACK
        if c is not None:
            f[(xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= 64] = RED
        frames.append(f)
    return encode_video(np.stack(frames), path, fps=5.0, lossless=True)


def test_headline_plot_shows_both_views_with_their_intervals_or_why_not():
    summary = {"headline": {"metric": "physics_score", "mean": 0.42, "ci": [0.1, 0.7], "n": 8,
                            "mean_model_success": 0.6, "ci_model_success": [0.3, 0.9],
                            "n_model_success": 5, "small_sample": True}}
    html = headline_plot(summary)
    assert [(r["data-view"], r["data-mean"], r["data-lo"], r["data-hi"], r["data-n"])
            for r in _attrs(html, "g", "headline-row")] == [
        ("all scored scenes", "0.42", "0.1", "0.7", "8"), ("model successes", "0.6", "0.3",
                                                            "0.9", "5")]
    assert "still clip" in html and "ground truth" in html and "read the interval" in html
    assert "<script" not in html
    none = headline_plot({"headline": None})
    assert "<svg" not in none and "no headline plot: the run has no headline score" in none


def test_family_bars_use_the_normalised_scores_where_the_run_has_them():
    metrics = {"physics_score": {"mean_model_success": 0.5, "n_model_success": 3},
               "psnr": {"direction": "higher", "mean_model_success": 30.0, "n_model_success": 3},
               "norm.psnr": {"mean_model_success": 0.7, "n_model_success": 3},
               "track_pos_err": {"direction": "lower", "mean_model_success": 12.0,
                                 "n_model_success": 2},
               "norm.track_pos_err": {"mean_model_success": 2.6, "n_model_success": 2},
               "rouge_l": {"direction": "higher", "mean_model_success": 0.4,
                           "n_model_success": 3},
               "ssim.aligned": {"direction": "higher", "mean_model_success": 0.9}}
    info = {"psnr": {"family": "pixel", "range": [0, 100]},
            "track_pos_err": {"family": "physics", "range": [0, float("inf")]},
            "rouge_l": {"family": "text", "range": [0, 1]}}
    html = family_bars({"metrics": metrics, "metric_info": info,
                        "headline": {"metric": "physics_score"}})
    assert 'data-scale="normalised"' in html
    bars = [(b["data-metric"], b["data-family"], b["data-value"], b["data-n"])
            for b in _attrs(html, "g", "bar")]
    # the plain pairing only, the headline left out; a metric without a normalised score is
    # listed without a bar, and a normalised value past the axis is drawn to its edge
    assert bars == [("psnr", "pixel", "0.7", "3"), ("track_pos_err", "physics", "2.6", "2"),
                    ("rouge_l", "text", "", "3")]
    assert "no bar: not normalised" in html and "›" in html


def test_family_bars_without_normalised_scores_place_the_mean_in_its_range_best_end_right():
    metrics = {"mse": {"direction": "lower", "mean_model_success": 0.2, "n_model_success": 4},
               "ssim": {"direction": "higher", "mean_model_success": 0.5, "n_model_success": 4},
               "flow_epe_dis": {"direction": "lower", "mean_model_success": 3.0,
                                "n_model_success": 4},
               "judge_gemini": {"direction": "higher", "mean_model_success": 7.0,
                                "n_model_success": 2},
               "fsim": {"direction": "higher", "mean_model_success": None,
                        "n_model_success": 0, "unavailable": "no weights"}}
    info = {"mse": {"family": "pixel", "range": [0, 1]},
            "ssim": {"family": "pixel", "range": [-1, 1]},
            "flow_epe_dis": {"family": "motion", "range": [0, float("inf")]},
            "fsim": {"family": "perceptual", "range": [0, 1]}}
    html = family_bars({"metrics": metrics, "metric_info": info})
    assert 'data-scale="range"' in html
    bars = {b["data-metric"]: (b["data-family"], b["data-value"])
            for b in _attrs(html, "g", "bar")}
    assert bars == {"mse": ("pixel", "0.8"), "ssim": ("pixel", "0.75"),
                    "flow_epe_dis": ("motion", ""), "judge_gemini": ("judges", "0.7"),
                    "fsim": ("perceptual", "")}
    assert "no bar: unbounded range" in html and "unavailable: no weights" in html
    assert "no family bars: no scores yet" in family_bars({"metrics": {}})


def test_frame_data_psnr_per_frame_and_each_body_located_in_both_clips(tmp_path):
    truth_path = [(30.0 + 8 * k, 50.0) for k in range(6)]
    gen_path = [(30.0, 40.0 + 6 * k) for k in range(5)] + [None]   # the ball leaves
    truth = _clip(tmp_path / "truth.mp4", truth_path)
    generated = _clip(tmp_path / "gen.mp4", gen_path)
    data = compute(truth, generated, SPEC, None)
    assert data["size"] == [128, 96] and data["n_truth"] == data["n_generated"] == 6
    assert len(data["psnr"]) == len(data["still"]) == 6
    assert data["still"][0] == 100.0   # the first frame against itself: the psnr metric's cap
    assert data["psnr"][0] is not None and data["psnr"][0] > 15
    tracks = data["tracks"]
    assert tracks["ids"] == ["red_ball", "blue_ball"]      # dynamic bodies of their own colour
    assert np.allclose(tracks["truth"][0], truth_path, atol=0.6)
    assert np.allclose(tracks["generated"][0][:5], gen_path[:5], atol=0.6)
    assert tracks["generated"][0][5] is None
    assert np.allclose(tracks["truth"][1], [(20, 20)] * 6, atol=0.6)
    # the metric details name the tracked bodies: only those are drawn
    only = compute(truth, generated, SPEC, {"tracks": {"tracked": ["red_ball"]}})
    assert only["tracks"]["ids"] == ["red_ball"]
    # clips of different sizes: no PSNR, the generated centroids in the truth's pixels
    big = _clip(tmp_path / "big.mp4", [(2 * x, 2 * y) for x, y in truth_path], (192, 256))
    scaled = compute(truth, big, SPEC, None)
    assert scaled["psnr_error"].startswith("frame sizes differ") and "psnr" not in scaled
    assert np.allclose(scaled["tracks"]["generated"][0], truth_path, atol=0.6)
    assert compute(truth, generated, {"bodies": "?"}, None)["tracks"] == \
        "no ground-truth spec with bodies (body colours unknown)"


def test_scene_plots_draw_one_point_per_frame_and_one_path_per_body_and_clip(tmp_path):
    truth = _clip(tmp_path / "truth.mp4", [(30.0 + 8 * k, 50.0) for k in range(6)])
    generated = _clip(tmp_path / "gen.mp4", [(30.0, 40.0 + 6 * k) for k in range(5)] + [None])
    frames = FrameData(tmp_path / "report")
    html = scene_plots("s", truth, None, generated, None, tmp_path / "none.json", frames,
                       [1, 4], "media/s/key_frame_01.png", fallback=False)
    curve = _attrs(html, "figure", "plot psnr-curve")
    assert curve == [{"data-frames": "6"}]
    series = _attrs(html, "g", "series")
    assert [s["data-series"] for s in series] == ["still clip (first frame held)", "generated"]
    assert series[0]["data-values"].startswith("100.0,")
    assert "key frame 4" in html
    # the spec is unknown here: the overlay says why
    assert "no track overlay: no ground-truth spec with bodies" in html
    assert "<script" not in html
    frames.close()
    assert (tmp_path / "report" / "media" / ".plots.json").is_file()
    # a clip missing on either side: one line, no plot
    assert "no plots: no generated clip" in scene_plots(
        "s", truth, None, tmp_path / "gone.mp4", None, tmp_path / "none.json", frames, [1],
        None, fallback=False)
    assert "no plots: ground truth not found" in scene_plots(
        "s", None, "ground truth not found", generated, None, tmp_path / "none.json", frames,
        [1], None, fallback=False)


def test_track_overlay_splits_a_path_where_the_body_is_not_found():
    data = {"size": [100, 80], "tracks": {
        "ids": ["red_ball"], "colours": [list(RED)],
        "truth": [[[10, 10], [20, 10], [30, 10], [40, 10]]],
        "generated": [[[10, 10], None, [30, 20], [40, 30]]]}}
    html = track_overlay(data, None)
    tracks = _attrs(html, "g", "track")
    assert [(t["data-body"], t["data-clip"], t["data-found"]) for t in tracks] == [
        ("red_ball", "ground truth", "4"), ("red_ball", "generated", "3")]
    paths = re.findall(r'<polyline class="path" points="([^"]*)"', html)
    assert paths == ["10,10 20,10 30,10 40,10", "10,10", "30,20 40,30"]
    assert 'viewBox="0 0 100 80"' in html and "<image" not in html and "blank canvas" in html
    assert "generated 3/4" in html


@pytest.mark.parametrize("values,note", [([100.0, 100.0], "identical frames"),
                                         ([20.0, 25.0], None)])
def test_psnr_curve_marks_each_frame_and_says_when_frames_are_identical(values, note):
    html = psnr_curve({"psnr": values, "still": [100.0, 21.0], "n_truth": 2,
                       "n_generated": 2}, [1], fallback=True)
    assert html.count('<circle') == 4 and "generated (fallback clip)" in html
    assert (note in html) if note else "identical frames" not in html
    assert "sizes differ" in psnr_curve({"psnr_error": "frame sizes differ (…)"}, [1], False)


def test_frame_data_finds_a_shaded_3d_body_by_its_chromaticity(tmp_path):
    """3D: a Lambert-shaded red sphere on a grey floor under a pale sky is found by the angle
    of its colour, whatever its brightness; the grey floor never counts as the body."""
    h, w = 96, 128
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    centres = [(40.0 + 10 * k, 48.0) for k in range(4)]
    frames = []
    for cx, cy in centres:
        f = np.zeros((h, w, 3), np.uint8)
        f[:] = (200, 210, 220)                            # sky
        f[60:] = (128, 128, 128)                          # floor
        inside = (xx - cx) ** 2 + (yy - cy) ** 2 <= 100
        shade = np.clip(1.1 - ((xx - cx + 4) ** 2 + (yy - cy + 4) ** 2) / 250, 0.35, 1.0)
        for ch, v in enumerate((220, 40, 30)):
            f[..., ch] = np.where(inside, (v * shade).astype(np.uint8), f[..., ch])
        frames.append(f)
    clip = encode_video(np.stack(frames), tmp_path / "c.mp4", fps=5.0, lossless=True)
    spec = {"dim": "3d", "render": {"background_rgb": [200, 210, 220]},
            "world": {"floor": {"color_rgb": [128, 128, 128]}},
            "bodies": [{"id": "ball", "dynamic": True, "color_rgb": [220, 40, 30]}]}
    data = compute(clip, clip, spec, None)
    assert data["tracks"]["ids"] == ["ball"]
    assert np.allclose(data["tracks"]["truth"][0], centres, atol=1.5)
    assert data["psnr"] == [100.0] * 4     # a clip against itself: the psnr metric's cap
