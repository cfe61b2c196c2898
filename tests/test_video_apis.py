"""Veo and Sora end to end: the real SDKs against fake servers on loopback."""

from __future__ import annotations

import asyncio
import base64
import tempfile
from pathlib import Path

import numpy as np
import pytest

from visphy_core.api.errors import ConfigError
from visphy_core.api.media import png_bytes
from visphy_core.api.model import ImageInput, ModelRequest, OutputContract
from visphy_core.api.registry import get_registry
from visphy_core.calls.keys import MissingKey
from visphy_core.config.check import compose
from visphy_core.infra.video import decode_video, encode_video, resize_with_padding
from visphy_plugins.models.baselines import decode_png
from visphy_plugins.models.video_apis import PROMPT, PROMPT_VERSION, SoraModel, VeoModel
from visphy_plugins.testing.fake_server import status
from visphy_plugins.testing.fake_sora import FakeSoraServer, form
from visphy_plugins.testing.fake_veo import FakeVeoServer

KEY = "test-video-key-0123456789"
CONTRACT = OutputContract(fps=5.0, n_frames=17, width=256, height=256)
GREYS = [20 + 30 * i for i in range(8)]


def key_frame(width: int = 256, height: int = 256) -> np.ndarray:
    rng = np.random.default_rng(3)
    frame = np.full((height, width, 3), 255, np.uint8)
    frame[height // 4: height // 2, width // 3: width // 2] = rng.integers(0, 255, 3)
    frame[-10:] = 60
    return frame


def provider_video(box: tuple[int, int], size: tuple[int, int] = (256, 144)) -> bytes:
    """What the fake provider returns: 8 frames at 24 fps; inside the key frame's box (columns
    box[0]:box[1]) frame i is grey GREYS[i], outside it stays white (the letterbox)."""
    w, h = size
    frames = []
    for grey in GREYS:
        f = np.full((h, w, 3), 255, np.uint8)
        f[:, box[0]:box[1]] = grey
        frames.append(f)
    with tempfile.TemporaryDirectory() as tmp:
        return encode_video(frames, Path(tmp) / "p.mp4", 24).read_bytes()


# 256×256 key frame in 1280×720: a 720×720 box at x = 280; in a 256×144 video: x 56..200
VIDEO = provider_video((56, 200))


def request(frame: np.ndarray | None = None) -> ModelRequest:
    frame = key_frame() if frame is None else frame
    return ModelRequest(scene_id="s1", prompt="write a program", detection=None,
                        images=[ImageInput("frame_01", png_bytes(frame)),
                                ImageInput("frame_10", png_bytes(frame))],
                        engine_name="video", language="mp4", output=CONTRACT)


@pytest.fixture(autouse=True)
def keys(monkeypatch, tmp_path):
    monkeypatch.setenv("VISPHY_ENV_FILE", str(tmp_path / "no.env"))
    monkeypatch.setenv("GEMINI_API_KEY", KEY)
    monkeypatch.setenv("OPENAI_API_KEY", KEY)


def model_for(name: str, url: str, *overrides: str):
    get_registry()
    cfg = compose([f"model={name}", f"model.base_url='{url}'", "model.poll_interval_s=0",
                   "model.retries.base_delay_s=0", *overrides]).model
    return get_registry().get("models", name)(cfg)


def run(model, req: ModelRequest):
    async def go():
        try:
            return await model.agenerate(req)
        finally:
            await model.aclose()
    return asyncio.run(go())


def expected_greys() -> list[int]:
    # output frame k is the provider frame on screen at k / 5 s (24 fps: 0, 4, then 7 held)
    return [GREYS[0], GREYS[4]] + [GREYS[7]] * (CONTRACT.n_frames - 2)


def check_clip(path: str) -> None:
    frames, info = decode_video(path)
    assert (info.n_frames, info.width, info.height, info.fps) == (17, 256, 256, 5.0)
    means = [float(f.mean()) for f in frames]
    assert means == pytest.approx(expected_greys(), abs=3.0)
    # the white letterbox was cut away: no frame has white edges
    assert all(f[:, :8].mean() < 240 and f[:, -8:].mean() < 240 for f in frames)


def key_nowhere_but_headers(requests, header: str) -> None:
    for r in requests:
        assert KEY not in r.raw_url and KEY.encode() not in r.body
        assert KEY in r.headers.get(header, "")


# ----------------------------------------------------------------------------------------- Veo
def test_veo_end_to_end():
    with FakeVeoServer(video=VIDEO, polls_before_done=2) as server:
        model = model_for("veo", server.url)
        model.check_ready()
        resp = run(model, request())
    assert resp.error is None, resp.error
    creates = [r for r in server.requests if r.path.endswith(":predictLongRunning")]
    assert len(creates) == 1
    create = creates[0]
    assert create.path == "/v1beta/models/veo-3.1-generate-preview:predictLongRunning"
    instance = create.json["instances"][0]
    assert instance["prompt"] == PROMPT
    assert instance["image"]["mimeType"] == "image/png"
    sent = decode_png(base64.b64decode(instance["image"]["bytesBase64Encoded"]))
    np.testing.assert_array_equal(sent, resize_with_padding(key_frame(), 1280, 720))
    params = create.json["parameters"]
    assert params["aspectRatio"] == "16:9" and params["resolution"] == "720p"
    assert params["durationSeconds"] == 4          # 16 frames at 5 fps after frame 1: 3.2 s
    polls = [r for r in server.requests if "/operations/" in r.path]
    assert len(polls) == 3 and all(r.method == "GET" for r in polls)
    downloads = [r for r in server.requests if r.path.endswith(":download")]
    assert len(downloads) == 1 and downloads[0].query == {"alt": ["media"]}
    key_nowhere_but_headers(server.requests, "x-goog-api-key")

    assert Path(resp.video_path).is_absolute() and "\n" not in resp.text
    check_clip(resp.video_path)
    assert resp.cost_usd == pytest.approx(0.40 * 4)
    assert resp.usage == {"video_seconds": 4}
    assert resp.transport_attempts == 5            # create + 3 polls + download
    assert resp.prompt_version == PROMPT_VERSION and resp.raw["polls"] == 3


def test_veo_failed_operation_is_a_server_error():
    with FakeVeoServer(video=VIDEO, polls_before_done=1) as server:
        server.fail_with = (13, "Video generation failed due to an internal error.")
        resp = run(model_for("veo", server.url), request())
    assert resp.video_path is None
    assert resp.error_kind == "server" and "internal error" in resp.error


def test_veo_content_filter_is_a_bad_request():
    with FakeVeoServer(video=VIDEO, polls_before_done=0) as server:
        server.filter_reasons = ["The input image violates the usage guidelines."]
        resp = run(model_for("veo", server.url), request())
    assert resp.error_kind == "bad_request" and "content filter" in resp.error


def test_veo_429_on_create_is_retried():
    with FakeVeoServer(video=VIDEO, polls_before_done=0) as server:
        server.script = [status(429, {"Retry-After": "0"}, "Resource has been exhausted")]
        resp = run(model_for("veo", server.url), request())
    assert resp.error is None, resp.error
    assert sum(r.path.endswith(":predictLongRunning") for r in server.requests) == 2
    assert resp.transport_attempts == 2 + 1 + 1
    check_clip(resp.video_path)


def test_veo_auth_failure_is_not_retried():
    with FakeVeoServer(video=VIDEO) as server:
        server.script = [status(403, message="API key not valid")]
        resp = run(model_for("veo", server.url), request())
    assert resp.error_kind == "auth" and server.count() == 1


def test_veo_gives_up_after_max_wait():
    with FakeVeoServer(video=VIDEO, polls_before_done=10**6) as server:
        resp = run(model_for("veo", server.url, "model.max_wait_s=1",
                             "model.poll_interval_s=0.05"), request())
    assert resp.error_kind == "timeout" and "not done after 1 s" in resp.error


def test_veo_portrait_key_frame_asks_for_9_16():
    frame = key_frame(128, 256)
    with FakeVeoServer(video=provider_video((0, 144), (144, 256)), polls_before_done=0) as s:
        resp = run(model_for("veo", s.url), request(frame))
    assert resp.error is None, resp.error
    create = s.requests[0].json
    assert create["parameters"]["aspectRatio"] == "9:16"
    sent = decode_png(base64.b64decode(create["instances"][0]["image"]["bytesBase64Encoded"]))
    assert sent.shape == (1280, 720, 3)


def test_veo_check_ready_names_the_missing_key(monkeypatch):
    monkeypatch.delenv("GEMINI_API_KEY")
    model = model_for("veo", "http://127.0.0.1:9")
    with pytest.raises(MissingKey, match="GEMINI_API_KEY"):
        model.check_ready()
    bad = model_for("veo", "http://127.0.0.1:9", "model.resolution=4k")
    with pytest.raises(ConfigError, match="720p, 1080p"):
        bad.check_ready()


# ---------------------------------------------------------------------------------------- Sora
def test_sora_end_to_end():
    with FakeSoraServer(video=VIDEO, polls_before_done=2) as server:
        model = model_for("sora", server.url + "/v1")
        model.check_ready()
        resp = run(model, request())
    assert resp.error is None, resp.error
    create = server.requests[0]
    assert (create.method, create.path) == ("POST", "/v1/videos")
    fields = form(create)
    assert fields["model"] == b"sora-2" and fields["prompt"].decode() == PROMPT
    assert fields["seconds"] == b"4" and fields["size"] == b"1280x720"
    np.testing.assert_array_equal(decode_png(fields["input_reference"]),
                                  resize_with_padding(key_frame(), 1280, 720))
    polls = [r for r in server.requests if r.method == "GET" and r.path == "/v1/videos/video_1"]
    assert len(polls) == 3
    assert [r.path for r in server.requests][-1] == "/v1/videos/video_1/content"
    key_nowhere_but_headers(server.requests, "authorization")

    check_clip(resp.video_path)
    assert resp.cost_usd == pytest.approx(0.10 * 4)
    assert resp.transport_attempts == 5 and resp.model_id == "sora-2"


def test_sora_failed_job_is_a_server_error():
    with FakeSoraServer(video=VIDEO, polls_before_done=1) as server:
        server.fail_with = ("internal_error", "The render failed.")
        resp = run(model_for("sora", server.url + "/v1"), request())
    assert resp.error_kind == "server" and "render failed" in resp.error


def test_sora_moderation_is_a_bad_request():
    with FakeSoraServer(video=VIDEO, polls_before_done=0) as server:
        server.fail_with = ("moderation_blocked", "Your request was blocked by our moderation "
                            "system.")
        resp = run(model_for("sora", server.url + "/v1"), request())
    assert resp.error_kind == "bad_request"
    with FakeSoraServer(video=VIDEO) as server:      # refused at create: 400, not retried
        server.script = [status(400, message="moderation_blocked: input image")]
        resp = run(model_for("sora", server.url + "/v1"), request())
    assert resp.error_kind == "bad_request" and server.count() == 1


def test_sora_429_on_create_is_retried():
    with FakeSoraServer(video=VIDEO, polls_before_done=0) as server:
        server.script = [status(429, {"Retry-After": "0"}, "Rate limit reached"),
                         status(503, message="overloaded")]
        resp = run(model_for("sora", server.url + "/v1"), request())
    assert resp.error is None, resp.error
    assert sum(r.method == "POST" for r in server.requests) == 3
    assert resp.transport_attempts == 3 + 1 + 1
    check_clip(resp.video_path)


def test_sora_check_ready(monkeypatch):
    model = model_for("sora", "http://127.0.0.1:9", "model.size=640x480")
    with pytest.raises(ConfigError, match="1280x720"):
        model.check_ready()
    monkeypatch.delenv("OPENAI_API_KEY")
    with pytest.raises(MissingKey, match="OPENAI_API_KEY"):
        model_for("sora", "http://127.0.0.1:9").check_ready()


def test_identity_ignores_transport_settings():
    a = model_for("veo", "http://127.0.0.1:1")
    b = model_for("veo", "http://127.0.0.1:2", "model.timeout_s=30")
    c = model_for("veo", "http://127.0.0.1:1", "model.resolution=1080p")
    assert a.identity() == b.identity() != c.identity()
    assert isinstance(a, VeoModel) and isinstance(model_for("sora", "x"), SoraModel)
    assert a.output_kind == "video"
