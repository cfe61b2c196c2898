"""Foreign clips are paired with the reference by their own timestamps, never by frame index.

Each source clip shows a dark square whose position is a known function of time; after
resampling to the reference contract (5 fps × 17 frames) the square must be where the function
puts it at k / 5 s, within a pixel, whatever the source's frame rate (35, 125, 1000 fps, or a
variable frame rate written with explicit PTS and a non-zero start time).
"""

from __future__ import annotations

import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from visphy_core.api.scene import Scene
from visphy_core.infra.cache import Cache
from visphy_core.infra.video import (
    ClipInfo,
    decode_video,
    decode_video_timed,
    encode_video,
    load_clip_for,
    normalise_clip,
    resample_by_time,
    shown_at,
)
from visphy_core.scoring.score import score_scene, to_contract
from visphy_plugins.metrics.pixel import PSNR

TARGET = ClipInfo(fps=5.0, n_frames=17, width=64, height=64)
DURATION_S = (TARGET.n_frames - 1) / TARGET.fps   # 3.2 s: the last reference frame's time
SQUARE = 8


def position(t: float) -> tuple[float, float]:
    """Top-left corner of the square (in 64×64 pixels) at time t seconds."""
    return 6.0 + 14.0 * t, 10.0 + 8.0 * t


def draw(t: float, scale: int = 1) -> np.ndarray:
    size = 64 * scale
    frame = np.full((size, size, 3), 255, np.uint8)
    x, y = (round(v * scale) for v in position(t))
    frame[y:y + SQUARE * scale, x:x + SQUARE * scale] = (20, 40, 160)
    return frame


def centroid(frame: np.ndarray) -> tuple[float, float]:
    dark = frame.mean(axis=2) < 128
    ys, xs = np.nonzero(dark)
    assert len(xs), "no square in the frame"
    return float(xs.mean()), float(ys.mean())


def expected_centroid(t: float) -> tuple[float, float]:
    x, y = position(t)
    return round(x) + (SQUARE - 1) / 2, round(y) + (SQUARE - 1) / 2


def max_error(frames: np.ndarray, times: list[float]) -> float:
    errs = []
    for frame, t in zip(frames, times):
        (cx, cy), (ex, ey) = centroid(frame), expected_centroid(t)
        errs.append(max(abs(cx - ex), abs(cy - ey)))
    return max(errs)


def constant_rate_clip(path: Path, fps: float, scale: int = 1) -> Path:
    n = int(np.ceil(DURATION_S * fps)) + 1
    return encode_video([draw(i / fps, scale) for i in range(n)], path, fps)


REFERENCE_TIMES = [k / TARGET.fps for k in range(TARGET.n_frames)]


@pytest.mark.parametrize("fps,scale", [(35, 1), (125, 2), (1000, 1)])
def test_constant_rate_clips_land_on_the_reference_times(tmp_path, fps, scale):
    path = constant_rate_clip(tmp_path / f"src{fps}.mp4", fps, scale)
    frames, times, info = decode_video_timed(path)
    assert info.fps == pytest.approx(fps)
    assert times[0] == 0.0
    np.testing.assert_allclose(times, np.arange(len(frames)) / fps, atol=1e-4)

    out = resample_by_time(frames, times, TARGET)
    assert out.shape == (17, 64, 64, 3)
    assert max_error(out, REFERENCE_TIMES) <= 1.0
    np.testing.assert_array_equal(load_clip_for(path, TARGET), out)

    # what scoring used to do: the reference's fps taken as the source's, i.e. frame k paired
    # with source frame k, which shows the square at k / fps s instead of k / 5 s
    by_index = normalise_clip(frames, TARGET.fps, TARGET)
    assert max_error(by_index, REFERENCE_TIMES) > 10
    # and the constant-rate helper with the right fps follows the same time rule
    np.testing.assert_array_equal(normalise_clip(frames, fps, TARGET), out)


def write_vfr(path: Path, stamps_ms: list[int]) -> Path:
    """A clip with explicit, irregular PTS (milliseconds) starting after zero."""
    with av.open(str(path), "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=30)
        stream.width = stream.height = 64
        stream.pix_fmt = "yuv420p"
        stream.codec_context.time_base = Fraction(1, 1000)
        stream.time_base = Fraction(1, 1000)
        start = stamps_ms[0]
        for ms in stamps_ms:
            frame = av.VideoFrame.from_ndarray(draw((ms - start) / 1000), format="rgb24")
            frame.pts, frame.time_base = ms, Fraction(1, 1000)
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def test_variable_frame_rate_clip_with_late_start(tmp_path):
    rng = np.random.default_rng(7)
    stamps = [700]                                  # the first frame is stamped 0.7 s
    while stamps[-1] - 700 < DURATION_S * 1000 + 200:
        stamps.append(stamps[-1] + int(rng.integers(7, 95)))
    path = write_vfr(tmp_path / "vfr.mp4", stamps)

    frames, times, info = decode_video_timed(path)
    assert len(frames) == len(stamps)
    np.testing.assert_allclose(times, (np.array(stamps) - 700) / 1000, atol=1e-3)

    out = resample_by_time(frames, times, TARGET)
    rel = [(ms - 700) / 1000 for ms in stamps]
    # the frame on screen at k/5 s: the last one stamped at or before it
    shown = [max(i for i, s in enumerate(rel) if s <= t + 5e-4) for t in REFERENCE_TIMES]
    assert max_error(out, [rel[i] for i in shown]) <= 1.0
    # index pairing is far off
    assert max_error(frames[:TARGET.n_frames], REFERENCE_TIMES) > 10


def test_shown_at_holds_first_and_last_frames():
    times = np.array([0.0, 0.1, 0.25])
    idx = shown_at(times, np.array([-1.0, 0.0, 0.0999, 0.1, 0.2, 0.2496, 10.0]))
    assert list(idx) == [0, 0, 1, 1, 1, 2, 2]   # 0.0999 + 0.5 ms tolerance reaches 0.1


def _scene(tmp_path: Path, clip: ClipInfo) -> Scene:
    return Scene(scene_id="timing_scene", dim="2d", clip=clip, video_path=tmp_path / "ref.mp4")


def test_scoring_pairs_a_foreign_clip_by_time(tmp_path):
    reference_path = constant_rate_clip(tmp_path / "ref.mp4", TARGET.fps)
    reference = decode_video(reference_path)[0][:TARGET.n_frames]
    scene = _scene(tmp_path, TARGET)
    path = constant_rate_clip(tmp_path / "src35.mp4", 35)
    frames, times, _ = decode_video_timed(path)

    cache = Cache(tmp_path / "cache")
    by_time, _ = score_scene(scene, reference, frames, [PSNR()], None, None, cache,
                             generated_times_s=times)
    wrong = normalise_clip(frames, TARGET.fps, TARGET)          # the old index pairing
    by_index, _ = score_scene(scene, reference, wrong, [PSNR()], None, None, cache)
    assert by_time["psnr"] > by_index["psnr"] + 5

    # without timestamps a clip of another frame count is refused, not paired by index
    with pytest.raises(ValueError, match="generated_times_s"):
        to_contract(scene, frames)
    # a clip on the contract's grid is left alone
    assert to_contract(scene, reference, np.arange(17) / 5.0) is reference


def _normalise(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "visphy_core", "normalise", *args],
                          capture_output=True, text=True, timeout=120)


def test_normalise_cli_copies_a_matching_clip_byte_for_byte(tmp_path):
    ref = constant_rate_clip(tmp_path / "ref.mp4", TARGET.fps)
    # same frames, same contract, but encoded with other settings: must not be re-encoded
    frames = decode_video(ref)[0]
    src = tmp_path / "other.mp4"
    with av.open(str(src), "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=5, options={"crf": "30"})
        stream.width, stream.height, stream.pix_fmt = 64, 64, "yuv420p"
        for frame in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    out = tmp_path / "out" / "n.mp4"
    proc = _normalise(str(src), "--like", str(ref), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    assert out.read_bytes() == src.read_bytes()
    assert "byte for byte" in proc.stdout and "no re-encode" in proc.stdout


def test_normalise_cli_resamples_a_35_fps_clip_by_time(tmp_path):
    ref = constant_rate_clip(tmp_path / "ref.mp4", TARGET.fps)
    src = constant_rate_clip(tmp_path / "src35.mp4", 35)
    out = tmp_path / "n.mp4"
    proc = _normalise(str(src), "--like", str(ref), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "resampled by timestamp" in proc.stdout
    frames, info = decode_video(out)
    ref_frames, ref_info = decode_video(ref)
    assert info == ref_info
    assert max_error(frames, REFERENCE_TIMES) <= 1.0
    assert np.abs(frames.astype(int) - ref_frames.astype(int)).mean() < 2.0
