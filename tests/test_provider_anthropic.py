"""The ``claude`` adapter end to end: `ApiModel` → `AnthropicClient` → the real ``anthropic``
SDK → a fake Messages API on loopback. Asserts what went over the wire and how every fault
ends (a retry or a classified failure), without ever reaching Anthropic."""

from __future__ import annotations

import asyncio
import base64
import gc
import io
from typing import Any, Callable

import pytest
from omegaconf import OmegaConf
from PIL import Image

from visphy_core.api.model import ImageInput, ModelRequest, ModelResponse, OutputContract
from visphy_core.calls.retry import CallError, CallErrorKind
from visphy_plugins.providers.base import ApiCaller, ApiModel, Part
from visphy_plugins.providers.config import ApiModelConfig, PriceConfig, RetriesConfig
from visphy_plugins.testing.fake_anthropic import FakeAnthropicServer
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

# The SDK flags claude-sonnet-4-5 as deprecated on every call; not what these tests are about.
pytestmark = pytest.mark.filterwarnings("ignore:The model .* is deprecated:DeprecationWarning")

KEY_ENV = "VISPHY_TEST_ANTHROPIC_KEY"
KEY = "sk-ant-test-0123456789-SECRET"
PROMPT = "Write a p5.js simulation of the two frames."


def png(color: tuple[int, int, int]) -> bytes:
    buf = io.BytesIO()
    Image.new("RGB", (8, 6), color).save(buf, format="PNG")
    return buf.getvalue()


IMAGES = [ImageInput("frame_0", png((255, 0, 0))), ImageInput("frame_1", png((0, 0, 255)))]


def request() -> ModelRequest:
    return ModelRequest(scene_id="s1", prompt=PROMPT, images=list(IMAGES), detection=None,
                        engine_name="p5", language="javascript",
                        output=OutputContract(5, 17, 512, 512))


def make_model(server: FakeAnthropicServer, **over: Any) -> ApiModel:
    fields: dict[str, Any] = dict(
        name="claude", provider="anthropic", model_id="claude-sonnet-4-5", api_key_env=KEY_ENV,
        base_url=server.url, max_output_tokens=4096, temperature=0.0, timeout_s=30.0,
        retries=RetriesConfig(max_attempts=3, base_delay_s=0.01, max_delay_s=0.05),
        price=PriceConfig(3.0, 15.0, 0.3))
    fields.update(over)
    return ApiModel(OmegaConf.structured(ApiModelConfig(**fields)))


def generate(model: ApiModel) -> ModelResponse:
    async def go() -> ModelResponse:
        try:
            return await model.agenerate(request())
        finally:
            await model.aclose()
    return asyncio.run(go())


@pytest.fixture(autouse=True)
def key(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(KEY_ENV, KEY)
    # SDK settings from the environment must not redirect or decorate the calls under test.
    for var in ("ANTHROPIC_BASE_URL", "ANTHROPIC_CUSTOM_HEADERS", "ANTHROPIC_API_KEY"):
        monkeypatch.delenv(var, raising=False)


class Server(FakeAnthropicServer):
    """The fake, plus hand-written reply bodies keyed by the ``ok`` text (odd shapes)."""

    def __init__(self) -> None:
        super().__init__()
        self.bodies: dict[str, Callable[[Recorded], dict]] = {}

    def ok_body(self, req: Recorded, text: str, usage: dict[str, int]) -> dict:
        if text in self.bodies:
            return self.bodies[text](req)
        return super().ok_body(req, text, usage)


@pytest.fixture
def server() -> Any:
    with Server() as srv:
        yield srv


# --------------------------------------------------------------------------- the wire


def test_request_on_the_wire_and_reply_parsed(server: Server) -> None:
    server.script = [ok("```js\nsketch()\n```", {"input_tokens": 1500, "output_tokens": 700,
                                                 "cached_input_tokens": 500})]
    resp = generate(make_model(server))

    assert server.count() == 1
    req = server.requests[0]
    assert (req.method, req.path, req.query) == ("POST", "/v1/messages", {})
    body = req.json
    assert body["model"] == "claude-sonnet-4-5"
    assert body["max_tokens"] == 4096
    assert body["temperature"] == 0.0 and "thinking" not in body
    assert [m["role"] for m in body["messages"]] == ["user"]
    content = body["messages"][0]["content"]
    assert [c["type"] for c in content] == ["text", "image", "image"]
    assert content[0]["text"] == PROMPT
    for block, img in zip(content[1:], IMAGES):
        assert block["source"]["type"] == "base64"
        assert block["source"]["media_type"] == "image/png"
        assert base64.b64decode(block["source"]["data"]) == img.png

    # The key travels in exactly one auth header (SDK 2.x: ``Authorization: Bearer``; older
    # SDKs: ``x-api-key``) and nowhere else.
    carrying = {k: v for k, v in req.headers.items() if KEY in v}
    assert carrying in ({"authorization": f"Bearer {KEY}"}, {"x-api-key": KEY})
    assert req.headers.get("anthropic-version")
    assert KEY not in req.raw_url and KEY.encode() not in req.body

    assert resp.error is None and resp.error_kind is None
    assert resp.text == "```js\nsketch()\n```"
    assert resp.usage == {"input_tokens": 1500, "output_tokens": 700, "cached_input_tokens": 500}
    assert resp.cost_usd == pytest.approx((1000 * 3.0 + 500 * 0.3 + 700 * 15.0) / 1e6)
    assert resp.finish_reason == "stop" and resp.refusal is None
    assert resp.model_id == "claude-sonnet-4-5"
    assert resp.transport_attempts == 1
    assert resp.raw["stop_reason"] == "end_turn" and resp.raw["id"].startswith("msg_")
    assert KEY not in repr(resp)


def test_cache_writes_count_as_input(server: Server) -> None:
    server.script = [ok("x", {"input_tokens": 2000, "output_tokens": 10,
                              "cache_creation_input_tokens": 300, "cached_input_tokens": 100})]
    resp = generate(make_model(server))
    assert resp.usage == {"input_tokens": 2000, "output_tokens": 10, "cached_input_tokens": 100}
    assert resp.raw["usage"]["cache_creation_input_tokens"] == 300


def test_temperature_left_out_when_null(server: Server) -> None:
    generate(make_model(server, temperature=None))
    assert "temperature" not in server.requests[0].json


def test_thinking_budget_sends_thinking_without_temperature(server: Server) -> None:
    server.bodies["thought"] = lambda req: {
        **server._reply(req, [], "end_turn", {"input_tokens": 10, "output_tokens": 5}),
        "content": [{"type": "thinking", "thinking": "hmm", "signature": "sig"},
                    {"type": "text", "text": "part one, "}, {"type": "text", "text": "two"}]}
    server.script = [ok("thought")]
    resp = generate(make_model(server, thinking_budget=2048))
    body = server.requests[0].json
    assert body["thinking"] == {"type": "enabled", "budget_tokens": 2048}
    assert "temperature" not in body and body["max_tokens"] == 4096
    assert resp.text == "part one, two"  # thinking blocks are not the answer


def test_thinking_budget_must_be_below_max_tokens(server: Server) -> None:
    resp = generate(make_model(server, thinking_budget=4096))
    assert resp.error_kind == "bad_request" and "thinking_budget" in (resp.error or "")
    assert server.count() == 0


def test_video_is_refused_without_a_request(server: Server) -> None:
    cfg = make_model(server).cfg
    caller = ApiCaller(cfg, "model=claude")

    async def go() -> Any:
        try:
            return await caller.complete([Part("text", text="hi"),
                                          Part("video", data=b"\x00\x00\x00\x18ftypmp42")])
        finally:
            await caller.aclose()

    result = asyncio.run(go())
    assert result.completion is None and result.error is not None
    assert result.error.kind.value == "bad_request" and "video" in str(result.error)
    assert result.attempts == 1 and server.count() == 0


# The first loop's idle keep-alive socket can only be reclaimed by the garbage collector.
@pytest.mark.filterwarnings("ignore::ResourceWarning")
def test_one_model_serves_two_event_loops(server: Server) -> None:
    model = make_model(server)
    # No `aclose` between the loops: the second must not reuse the dead loop's SDK client.
    first = asyncio.run(model.agenerate(request()))
    second = asyncio.run(model.agenerate(request()))
    asyncio.run(model.aclose())
    gc.collect()
    assert first.error is None and second.error is None and server.count() == 2


# --------------------------------------------------------------------------- faults


def test_429_with_retry_after_zero_is_retried(server: Server) -> None:
    server.script = [status(429, {"retry-after": "0"}), ok("done")]
    resp = generate(make_model(server))
    assert resp.error is None and resp.text == "done"
    assert resp.transport_attempts == 2 and server.count() == 2


def test_retry_after_is_waited(server: Server) -> None:
    server.script = [status(429, {"retry-after": "0.3"}), ok("done")]
    resp = generate(make_model(server))
    assert resp.error is None and server.count() == 2
    gap = server.requests[1].time - server.requests[0].time
    assert gap >= 0.28  # the 0.01 s backoff would not come close


def test_529_overloaded_is_retried(server: Server) -> None:
    server.script = [status(529, message="Overloaded"), ok("done")]
    resp = generate(make_model(server))
    assert resp.error is None and resp.text == "done" and resp.transport_attempts == 2


def test_persistent_500_fails_as_server(server: Server) -> None:
    server.default = lambda req: status(500)
    resp = generate(make_model(server))
    assert resp.error_kind == "server" and "500" in (resp.error or "")
    assert resp.text == "" and resp.transport_attempts == 3 and server.count() == 3


def test_client_timeout(server: Server) -> None:
    server.default = lambda req: delay(3.0, ok("late"))
    resp = generate(make_model(server, timeout_s=1.0,
                               retries=RetriesConfig(max_attempts=2, base_delay_s=0.01)))
    assert resp.error_kind == "timeout"
    assert resp.transport_attempts == 2 and server.count() == 2


def test_malformed_json_is_retried(server: Server) -> None:
    server.script = [malformed(), ok("done")]
    resp = generate(make_model(server))
    assert resp.error is None and resp.text == "done" and resp.transport_attempts == 2


def test_persistent_malformed_fails_as_malformed(server: Server) -> None:
    server.default = lambda req: malformed()
    resp = generate(make_model(server))
    assert resp.error_kind == "malformed" and server.count() == 3


def test_body_without_content_is_malformed(server: Server) -> None:
    server.bodies["bare"] = lambda req: {"type": "message", "id": "msg_x"}
    server.default = lambda req: ok("bare")
    resp = generate(make_model(server))
    assert resp.error_kind == "malformed" and server.count() == 3


def test_truncated_is_a_success_with_length(server: Server) -> None:
    server.script = [truncated("function sketch() {")]
    resp = generate(make_model(server))
    assert resp.error is None and resp.text == "function sketch() {"
    assert resp.finish_reason == "length" and resp.truncated and server.count() == 1


def test_refusal(server: Server) -> None:
    server.script = [refusal("I can't help with that.")]
    resp = generate(make_model(server))
    assert resp.error is None and resp.finish_reason == "refusal"
    assert resp.refusal == "I can't help with that." and server.count() == 1


def test_empty_content_is_retried_then_fails(server: Server) -> None:
    server.script = [empty(), ok("done")]
    resp = generate(make_model(server))
    assert resp.error is None and resp.text == "done" and resp.transport_attempts == 2

    server.script, server.requests = [], []
    server.default = lambda req: empty()
    resp = generate(make_model(server))
    assert resp.error_kind == "empty" and server.count() == 3


def test_401_is_auth_without_retry(server: Server) -> None:
    server.default = lambda req: status(401, message="invalid x-api-key")
    resp = generate(make_model(server))
    assert resp.error_kind == "auth" and server.count() == 1 and resp.transport_attempts == 1
    assert KEY not in (resp.error or "")


def test_400_is_bad_request_without_retry(server: Server) -> None:
    server.default = lambda req: status(400, message="max_tokens: too large")
    resp = generate(make_model(server))
    assert resp.error_kind == "bad_request" and server.count() == 1
    assert "too large" in (resp.error or "")


def test_dropped_connection(server: Server) -> None:
    server.default = lambda req: drop()
    resp = generate(make_model(server))
    assert resp.error_kind == "connection" and server.count() == 3


@pytest.mark.parametrize("stop,finish", [("end_turn", "stop"), ("stop_sequence", "stop"),
                                         ("max_tokens", "length"),
                                         ("model_context_window_exceeded", "length"),
                                         ("pause_turn", "other"), ("tool_use", "other")])
def test_stop_reasons(server: Server, stop: str, finish: str) -> None:
    server.bodies["x"] = lambda req: server._reply(
        req, [{"type": "text", "text": "t"}], stop, {"input_tokens": 1, "output_tokens": 1})
    server.script = [ok("x")]
    assert generate(make_model(server)).finish_reason == finish


# --------------------------------------------------------------------------- the client alone


def test_sdk_timeout_is_classified(server: Server) -> None:
    """Without `ApiCaller`'s own deadline racing it, the SDK's timeout is what fires."""
    from visphy_plugins.providers.anthropic_api import AnthropicClient

    server.default = lambda req: delay(2.0, ok("late"))
    client = AnthropicClient(make_model(server, timeout_s=1.0).cfg, KEY)

    async def go() -> None:
        try:
            await client.complete([Part("text", text="hi")], 64)
        finally:
            await client.aclose()

    with pytest.raises(CallError) as info:
        asyncio.run(go())
    assert info.value.kind is CallErrorKind.timeout


def test_non_message_reply_is_malformed() -> None:
    """A non-JSON content type makes the SDK return the body as a ``str``."""
    from visphy_plugins.providers.anthropic_api import to_completion

    with pytest.raises(CallError) as info:
        to_completion("<html>bad gateway</html>")
    assert info.value.kind is CallErrorKind.malformed
