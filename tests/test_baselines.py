"""Offline pixel-space baselines: ``static`` and ``flow_extrapolate``."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from visphy_core.api.model import ImageInput, ModelRequest, OutputContract
from visphy_core.api.registry import get_registry
from visphy_core.infra.png import decode_png, png_bytes
from visphy_core.infra.video import decode_video, resize_with_padding
from visphy_plugins.models.baselines import (
    FlowExtrapolateModel,
    StaticModel,
    extrapolate,
    key_frame_index,
    static_frames,
)

SIZE = 128
CONTRACT = OutputContract(fps=5.0, n_frames=17, width=SIZE, height=SIZE)
START = (40.0, 50.0)
SHIFT = (6.0, 3.0)          # disc displacement between frame 1 and frame 10


def disc_frame(cx: float, cy: float, size: int = SIZE) -> np.ndarray:
    frame = np.full((size, size, 3), 255, np.uint8)
    frame[size - 12:] = (90, 90, 90)   # a still floor: its flow must stay zero
    cv2.circle(frame, (round(cx * 16), round(cy * 16)), 12 * 16, (200, 40, 40), -1,
               lineType=cv2.LINE_AA, shift=4)
    return frame


def centroid(frame: np.ndarray) -> tuple[float, float]:
    red = (frame[..., 0].astype(int) - frame[..., 1].astype(int)) > 80
    ys, xs = np.nonzero(red)
    assert len(xs) > 100, "the disc is gone"
    return float(xs.mean()), float(ys.mean())


def request(images: list[tuple[str, np.ndarray]], contract: OutputContract = CONTRACT
            ) -> ModelRequest:
    return ModelRequest(scene_id="s", prompt="p",
                        images=[ImageInput(name, png_bytes(f)) for name, f in images],
                        detection=None, engine_name="video", language="mp4", output=contract)


def pair() -> list[tuple[str, np.ndarray]]:
    return [("frame_01", disc_frame(*START)),
            ("frame_10", disc_frame(START[0] + SHIFT[0], START[1] + SHIFT[1]))]


def test_key_frame_names_give_indices():
    assert key_frame_index(ImageInput("frame_01", b"")) == 1
    assert key_frame_index(ImageInput("frame_10", b"")) == 10
    with pytest.raises(ValueError, match="no frame number"):
        key_frame_index(ImageInput("first", b""))


def test_static_repeats_the_first_key_frame(tmp_path):
    images = pair()
    req = request(images)
    first = decode_png(req.images[0].png)
    np.testing.assert_array_equal(first, images[0][1])          # PNG round trip is exact
    frames = static_frames(first, CONTRACT)
    assert frames.shape == (17, SIZE, SIZE, 3)
    assert all(np.array_equal(f, first) for f in frames)         # exactly, every frame

    resp = StaticModel().generate(req)
    assert resp.error is None and resp.video_path and Path(resp.video_path).is_absolute()
    assert "frame_01" in resp.text and "\n" not in resp.text
    video, info = decode_video(resp.video_path)
    assert (info.n_frames, info.width, info.height, info.fps) == (17, SIZE, SIZE, 5.0)
    # H.264 (yuv420p, crf 12) is near-lossless on flat colours, not bit-exact
    assert np.abs(video.astype(int) - first.astype(int)).mean() < 1.0
    assert all(np.array_equal(video[0], f) for f in video)      # and identical frame to frame


def test_static_fits_a_key_frame_of_another_size():
    small = disc_frame(20, 25, size=64)[:, :48]                  # 48×64, not the contract's
    resp = StaticModel().generate(request([("frame_01", small)]))
    video, info = decode_video(resp.video_path)
    assert (info.width, info.height) == (SIZE, SIZE)
    expected = resize_with_padding(small, SIZE, SIZE)
    assert np.abs(video[5].astype(int) - expected.astype(int)).mean() < 1.5


def test_flow_extrapolate_continues_the_motion_linearly():
    images = pair()
    first, second = images[0][1], images[1][1]
    frames, flow = extrapolate(first, second, 1, 10, CONTRACT)
    assert frames.shape == (17, SIZE, SIZE, 3)
    for k in (0, 4, 9, 12, 16):
        s = k / 9                                                # (k + 1 - 1) / (10 - 1)
        ex, ey = START[0] + SHIFT[0] * s, START[1] + SHIFT[1] * s
        cx, cy = centroid(frames[k])
        assert abs(cx - ex) <= 2.0 and abs(cy - ey) <= 2.0, (k, (cx, cy), (ex, ey))
    np.testing.assert_array_equal(frames[0], first)              # frame 1 is the first key
    # frame 10 (k = 9) is reproduced
    assert np.abs(frames[9].astype(int) - second.astype(int)).mean() < 1.0
    assert centroid(frames[9]) == pytest.approx(centroid(second), abs=0.5)
    # the floor does not move
    assert np.abs(frames[16][-8:].astype(int) - first[-8:].astype(int)).max() <= 2


def test_flow_extrapolate_model_writes_the_clip_deterministically():
    req = request(pair())
    a = FlowExtrapolateModel().generate(req)
    b = FlowExtrapolateModel().generate(req)
    assert a.error is None and "frame_01->frame_10" in a.text and "\n" not in a.text
    assert Path(a.video_path).read_bytes() == Path(b.video_path).read_bytes()
    video, info = decode_video(a.video_path)
    assert (info.n_frames, info.width, info.height) == (17, SIZE, SIZE)
    cx, cy = centroid(video[16])
    assert abs(cx - (START[0] + SHIFT[0] * 16 / 9)) <= 2.0
    assert abs(cy - (START[1] + SHIFT[1] * 16 / 9)) <= 2.0
    assert a.raw["frames"] == [1, 10]


def test_flow_extrapolate_uses_the_key_frame_numbers():
    # the same pair shown as frames 5 and 8: three frames apart, so twice as fast (per
    # frame: shift / 3), and frame 5 is output frame k = 4
    first, second = pair()[0][1], pair()[1][1]
    frames, _ = extrapolate(first, second, 5, 8, CONTRACT)
    np.testing.assert_array_equal(frames[4], first)
    cx, cy = centroid(frames[5])                                 # one frame after the first
    assert abs(cx - (START[0] + SHIFT[0] / 3)) <= 1.0 and abs(cy - (START[1] + SHIFT[1] / 3)) <= 1.0


def test_forecast_only_degrades_to_static():
    first = pair()[0][1]
    resp = FlowExtrapolateModel().generate(request([("frame_01", first)]))
    assert resp.error is None
    assert "forecast-only" in resp.text and "static" in resp.text
    assert resp.raw["degraded_to"] == "static"
    static = StaticModel().generate(request([("frame_01", first)]))
    assert Path(resp.video_path).read_bytes() == Path(static.video_path).read_bytes()


def test_same_key_frame_twice_is_a_bad_request():
    first = pair()[0][1]
    resp = FlowExtrapolateModel().generate(request([("frame_03", first), ("frame_03", first)]))
    assert resp.error_kind == "bad_request" and resp.video_path is None


def test_baselines_are_registered_video_models():
    registry = get_registry()
    for name in ("static", "flow_extrapolate"):
        model = registry.get("models", name)(None)
        assert model.output_kind == "video" and model.name == name
        assert model.baseline and model.describe()["baseline"] is True  # no model's successes
    assert registry.get("models", "oracle")(None).baseline is False
