"""The OpenAI-family client, driven end to end: `ApiModel` -> official SDK -> real HTTP on
loopback -> `FakeOpenAIServer`. Asserts what the server received (the wire format) and what
the model adapter made of each reply or fault (retries, classification, cost)."""

from __future__ import annotations

import asyncio
import base64
import io
import json
import threading
from typing import Any

import pytest
from omegaconf import OmegaConf
from PIL import Image

from visphy_core.api.model import ImageInput, ModelRequest, ModelResponse, OutputContract
from visphy_plugins.providers.base import ApiCaller, ApiModel, Part
from visphy_plugins.providers.config import (
    ApiModelConfig,
    ConcurrencyConfig,
    PriceConfig,
    RetriesConfig,
)
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.fake_server import (
    Recorded,
    delay,
    drop,
    empty,
    malformed,
    ok,
    refusal,
    status,
    truncated,
)

KEY_ENV = "VISPHY_TEST_OPENAI_KEY"
KEY = "sk-test-0penai-Very5ecretValue-9f3c"
MAX_ATTEMPTS = 3


def png(color: tuple[int, int, int], size: tuple[int, int] = (8, 6)) -> bytes:
    buf = io.BytesIO()
    Image.new("RGB", size, color).save(buf, format="PNG")
    return buf.getvalue()


PNG_A = png((255, 0, 0))
PNG_B = png((0, 0, 255), (5, 7))


@pytest.fixture(autouse=True)
def api_key(monkeypatch: pytest.MonkeyPatch) -> str:
    monkeypatch.setenv(KEY_ENV, KEY)
    return KEY


@pytest.fixture
def server():
    with FakeOpenAIServer() as srv:
        yield srv


def make_model(base_url: str, **overrides: Any) -> ApiModel:
    fields: dict[str, Any] = dict(
        name="gpt5", provider="openai", model_id="gpt-5", api_key_env=KEY_ENV,
        base_url=base_url, max_output_tokens=32768,
        max_tokens_param="max_completion_tokens", timeout_s=10.0,
        retries=RetriesConfig(max_attempts=MAX_ATTEMPTS, base_delay_s=0.01, max_delay_s=0.05),
        price=PriceConfig(input_usd_per_mtok=1.25, output_usd_per_mtok=10.0,
                          cached_input_usd_per_mtok=0.125))
    fields.update(overrides)
    return ApiModel(OmegaConf.structured(ApiModelConfig(**fields)))


def make_request() -> ModelRequest:
    return ModelRequest(scene_id="scene-1", prompt="Write a simulator of this scene.",
                        images=[ImageInput("frame_000", PNG_A), ImageInput("frame_008", PNG_B)],
                        detection=None, engine_name="p5", language="javascript",
                        output=OutputContract(5, 17, 512, 512))


def generate(model: ApiModel, request: ModelRequest | None = None) -> ModelResponse:
    async def go() -> ModelResponse:
        try:
            return await model.agenerate(request or make_request())
        finally:
            await model.aclose()

    return asyncio.run(go())


def assert_key_only_in_auth(req: Recorded) -> None:
    assert req.headers["authorization"] == f"Bearer {KEY}"
    assert KEY not in req.raw_url
    assert KEY not in req.body.decode()
    assert not [k for k, v in req.headers.items() if KEY in v and k != "authorization"]


def decode_data_url(url: str, mime: str) -> bytes:
    prefix = f"data:{mime};base64,"
    assert url.startswith(prefix)
    return base64.b64decode(url[len(prefix):])


# --------------------------------------------------------------------------- the wire format
def test_gpt5_request_and_reply(server: FakeOpenAIServer) -> None:
    server.script = [ok("```js\nconsole.log(1)\n```", {"input_tokens": 1000, "output_tokens": 200,
                                                       "cached_input_tokens": 400,
                                                       "reasoning_tokens": 150})]
    resp = generate(make_model(server.url + "/v1"))

    assert server.count() == 1
    req = server.requests[0]
    assert (req.method, req.path) == ("POST", "/v1/chat/completions")
    body = req.json
    assert body["model"] == "gpt-5"
    assert body["max_completion_tokens"] == 32768 and "max_tokens" not in body
    for absent in ("temperature", "seed", "reasoning_effort"):
        assert absent not in body
    [message] = body["messages"]
    assert message["role"] == "user"
    text, img1, img2 = message["content"]
    assert text == {"type": "text", "text": "Write a simulator of this scene."}
    for part, expected in ((img1, PNG_A), (img2, PNG_B)):
        assert part["type"] == "image_url"
        assert part["image_url"]["detail"] == "high"
        assert decode_data_url(part["image_url"]["url"], "image/png") == expected
    assert_key_only_in_auth(req)

    assert resp.error is None and resp.error_kind is None
    assert resp.text == "```js\nconsole.log(1)\n```"
    assert resp.usage == {"input_tokens": 1000, "output_tokens": 200,
                          "cached_input_tokens": 400, "reasoning_tokens": 150}
    assert resp.cost_usd == pytest.approx((600 * 1.25 + 400 * 0.125 + 200 * 10.0) / 1e6)
    assert resp.finish_reason == "stop" and resp.refusal is None
    assert resp.model_id == "gpt-5"
    assert resp.transport_attempts == 1
    assert resp.raw["finish_reason"] == "stop" and resp.raw["usage"] == resp.usage
    assert KEY not in json.dumps(resp.raw)


def test_qwen_style_config_uses_max_tokens_and_set_knobs(server: FakeOpenAIServer) -> None:
    model = make_model(server.url + "/compatible-mode/v1", name="qwen3vlplus",
                       model_id="qwen3-vl-plus", max_output_tokens=16384,
                       max_tokens_param="max_tokens", temperature=0.0, seed=7,
                       price=PriceConfig(input_usd_per_mtok=0.2, output_usd_per_mtok=1.6))
    server.script = [ok("hi", {"input_tokens": 100, "output_tokens": 50})]
    resp = generate(model)

    req = server.requests[0]
    assert req.path == "/compatible-mode/v1/chat/completions"
    body = req.json
    assert body["model"] == "qwen3-vl-plus"
    assert body["max_tokens"] == 16384 and "max_completion_tokens" not in body
    assert body["temperature"] == 0.0 and body["seed"] == 7  # 0.0 is set, not omitted
    assert "reasoning_effort" not in body
    assert_key_only_in_auth(req)
    assert resp.text == "hi" and resp.model_id == "qwen3-vl-plus"
    assert resp.usage == {"input_tokens": 100, "output_tokens": 50, "cached_input_tokens": 0,
                          "reasoning_tokens": 0}
    assert resp.cost_usd == pytest.approx((100 * 0.2 + 50 * 1.6) / 1e6)


def test_reasoning_effort_and_video_parts(server: FakeOpenAIServer) -> None:
    """Judges send videos through `ApiCaller`; DashScope accepts ``video_url`` data URLs."""
    cfg = OmegaConf.create({"provider": "openai", "model_id": "qwen3-vl-plus",
                            "api_key_env": KEY_ENV, "base_url": server.url + "/v1",
                            "max_output_tokens": 64, "max_tokens_param": "max_tokens",
                            "reasoning_effort": "low", "image_detail": "low",
                            "retries": {"max_attempts": 1}})
    video = b"\x00\x00\x00\x18ftypmp42fake-video"
    caller = ApiCaller(cfg, "judge=test")

    async def go():
        try:
            return await caller.complete([Part("text", text="judge"), Part("video", data=video),
                                          Part("image", data=PNG_A)])
        finally:
            await caller.aclose()

    result = asyncio.run(go())
    assert result.error is None and result.completion is not None
    body = server.requests[0].json
    assert body["reasoning_effort"] == "low" and body["max_tokens"] == 64
    _, vid, img = body["messages"][0]["content"]
    assert vid["type"] == "video_url"
    assert decode_data_url(vid["video_url"]["url"], "video/mp4") == video
    assert img["image_url"]["detail"] == "low"
    assert result.cost_usd is None  # no price table: cost not tracked


def test_sequential_generate_calls_reuse_the_model(server: FakeOpenAIServer) -> None:
    """`Model.generate` runs each call in its own event loop; the SDK client must follow."""
    model = make_model(server.url + "/v1")
    first, second = model.generate(make_request()), model.generate(make_request())
    assert first.error is None and second.error is None
    assert server.count() == 2


# --------------------------------------------------------------------------- faults
def test_429_retry_after_zero_then_ok(server: FakeOpenAIServer) -> None:
    server.script = [status(429, {"Retry-After": "0"}), ok("after the limit")]
    resp = generate(make_model(server.url + "/v1"))
    assert server.count() == 2
    assert resp.error is None and resp.text == "after the limit"
    assert resp.transport_attempts == 2


def test_429_retry_after_is_waited(server: FakeOpenAIServer) -> None:
    server.script = [status(429, {"Retry-After": "0.3"}), ok("waited")]
    resp = generate(make_model(server.url + "/v1"))
    assert resp.error is None and resp.transport_attempts == 2
    first, second = server.requests
    assert second.time - first.time >= 0.3
    assert resp.latency_s >= 0.3


def test_500_twice_then_ok(server: FakeOpenAIServer) -> None:
    server.script = [status(500), status(500), ok("third time")]
    resp = generate(make_model(server.url + "/v1"))
    assert server.count() == 3
    assert resp.error is None and resp.text == "third time" and resp.transport_attempts == 3


def test_persistent_500_is_a_server_error() -> None:
    with FakeOpenAIServer(default=lambda req: status(503)) as srv:
        resp = generate(make_model(srv.url + "/v1"))
        assert srv.count() == MAX_ATTEMPTS
    assert resp.error_kind == "server" and resp.text == ""
    assert resp.transport_attempts == MAX_ATTEMPTS
    assert "HTTP 503" in (resp.error or "")


def test_client_timeout_retried_then_ok(server: FakeOpenAIServer) -> None:
    server.script = [delay(1.5, ok("late")), ok("on time")]
    resp = generate(make_model(server.url + "/v1", timeout_s=0.3))
    assert server.count() == 2
    assert resp.error is None and resp.text == "on time" and resp.transport_attempts == 2


def test_persistent_timeout() -> None:
    with FakeOpenAIServer(default=lambda req: delay(1.0, ok("late"))) as srv:
        resp = generate(make_model(srv.url + "/v1", timeout_s=0.2))
        assert srv.count() == MAX_ATTEMPTS
    assert resp.error_kind == "timeout" and resp.transport_attempts == MAX_ATTEMPTS


def test_malformed_json_retried_then_ok(server: FakeOpenAIServer) -> None:
    server.script = [malformed(), ok("parsed")]
    resp = generate(make_model(server.url + "/v1"))
    assert resp.error is None and resp.text == "parsed" and resp.transport_attempts == 2


def test_persistent_malformed() -> None:
    with FakeOpenAIServer(default=lambda req: malformed()) as srv:
        resp = generate(make_model(srv.url + "/v1"))
        assert srv.count() == MAX_ATTEMPTS
    assert resp.error_kind == "malformed"


@pytest.mark.parametrize("body", [b"{}", b"[]", b'{"choices": []}', b"<html>proxy</html>",
                                  b'{"choices": [{"message": null}]}'])
def test_json_that_is_not_a_completion_is_malformed(body: bytes) -> None:
    """The SDK validates non-strictly and hands such bodies back as they decoded."""

    class Odd(FakeOpenAIServer):
        def _serve(self, handler, req):  # type: ignore[no-untyped-def]
            self._next(req)
            self._send(handler, 200, body, content_type="text/html" if b"<" in body
                       else "application/json")

    with Odd() as srv:
        resp = generate(make_model(srv.url + "/v1"))
        assert srv.count() == MAX_ATTEMPTS
    assert resp.error_kind == "malformed"


def test_truncated_is_a_success_with_length(server: FakeOpenAIServer) -> None:
    server.script = [truncated("function step(")]
    resp = generate(make_model(server.url + "/v1"))
    assert server.count() == 1
    assert resp.error is None and resp.text == "function step("
    assert resp.finish_reason == "length" and resp.truncated


def test_refusal(server: FakeOpenAIServer) -> None:
    server.script = [refusal("I can't help with that.")]
    resp = generate(make_model(server.url + "/v1"))
    assert server.count() == 1
    assert resp.error is None and resp.text == ""
    assert resp.finish_reason == "refusal" and resp.refusal == "I can't help with that."


def test_empty_reply_retried_then_empty() -> None:
    with FakeOpenAIServer(default=lambda req: empty()) as srv:
        resp = generate(make_model(srv.url + "/v1"))
        assert srv.count() == MAX_ATTEMPTS
    assert resp.error_kind == "empty"


def test_401_is_auth_without_retry_and_key_is_scrubbed(server: FakeOpenAIServer) -> None:
    server.script = [status(401, message=f"Incorrect API key provided: {KEY}.")]
    resp = generate(make_model(server.url + "/v1"))
    assert server.count() == 1
    assert resp.error_kind == "auth" and resp.transport_attempts == 1
    assert "HTTP 401" in (resp.error or "") and KEY not in (resp.error or "")


def test_400_is_bad_request_without_retry(server: FakeOpenAIServer) -> None:
    server.script = [status(400, message="Unsupported parameter: 'max_tokens'")]
    resp = generate(make_model(server.url + "/v1"))
    assert server.count() == 1
    assert resp.error_kind == "bad_request" and "max_tokens" in (resp.error or "")


def test_dropped_connection_retried_then_ok(server: FakeOpenAIServer) -> None:
    server.script = [drop(), ok("reconnected")]
    resp = generate(make_model(server.url + "/v1"))
    assert server.count() == 2
    assert resp.error is None and resp.text == "reconnected"


def test_persistent_drop_is_a_connection_error() -> None:
    with FakeOpenAIServer(default=lambda req: drop()) as srv:
        resp = generate(make_model(srv.url + "/v1"))
        assert srv.count() == MAX_ATTEMPTS
    assert resp.error_kind == "connection"


# --------------------------------------------------------------------------- concurrency
class InFlightServer(FakeOpenAIServer):
    """Counts the requests being served at once, from arrival until the reply starts (not
    until it ends: the client may free its slot and send the next request before the serving
    thread returns, which would count one request twice)."""

    def __init__(self, **kw: Any):
        super().__init__(**kw)
        self.in_flight = 0
        self.peak = 0
        self._count_lock = threading.Lock()
        self._local = threading.local()

    def _leave(self) -> None:
        if getattr(self._local, "inside", False):
            self._local.inside = False
            with self._count_lock:
                self.in_flight -= 1

    def _send(self, handler, *args, **kw):  # type: ignore[no-untyped-def]
        self._leave()
        super()._send(handler, *args, **kw)

    def _serve(self, handler, req):  # type: ignore[no-untyped-def]
        with self._count_lock:
            self.in_flight += 1
            self.peak = max(self.peak, self.in_flight)
        self._local.inside = True
        try:
            super()._serve(handler, req)
        finally:
            self._leave()


def test_limiter_caps_concurrency() -> None:
    with InFlightServer(default=lambda req: delay(0.2, ok("slow"))) as srv:
        model = make_model(srv.url + "/v1",
                           concurrency=ConcurrencyConfig(initial=3, maximum=3))

        async def go() -> list[ModelResponse]:
            try:
                return list(await asyncio.gather(*(model.agenerate(make_request())
                                                   for _ in range(12))))
            finally:
                await model.aclose()

        responses = asyncio.run(go())
        assert srv.count() == 12
    assert all(r.error is None for r in responses)
    assert srv.peak == 3
