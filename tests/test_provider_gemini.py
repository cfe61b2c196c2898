"""The Gemini adapter end to end: `ApiModel` -> `GeminiClient` -> the real ``google-genai`` SDK ->
HTTP -> `FakeGeminiServer` on loopback. Every test checks what arrived at the server (the wire
format, where the key went) or how a fault was retried and classified."""

from __future__ import annotations

import asyncio
import base64
import io
from typing import Any

import pytest
from omegaconf import OmegaConf
from PIL import Image

from visphy_core.api.model import ImageInput, ModelRequest, ModelResponse, OutputContract
from visphy_plugins.providers.base import ApiModel, Part, make_client
from visphy_plugins.providers.config import ApiModelConfig, PriceConfig, RetriesConfig
from visphy_plugins.testing.fake_gemini import FakeGeminiServer, blocked_candidate, model_of
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

KEY = "test-gemini-key-3f9a1c"
PROMPT = "Write a simulator of the scene shown in the key frames."


def png(color: tuple[int, int, int]) -> bytes:
    buf = io.BytesIO()
    Image.new("RGB", (8, 6), color).save(buf, format="PNG")
    return buf.getvalue()


IMAGES = [ImageInput("frame_000", png((255, 0, 0))), ImageInput("frame_016", png((0, 0, 255)))]


@pytest.fixture(autouse=True)
def key_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VISPHY_TEST_GEMINI_KEY", KEY)
    for var in ("GEMINI_API_KEY", "GOOGLE_API_KEY", "GOOGLE_GENAI_USE_VERTEXAI",
                "GOOGLE_GENAI_USE_ENTERPRISE", "GOOGLE_GENAI_API_VERSION"):
        monkeypatch.delenv(var, raising=False)


@pytest.fixture
def server():
    with FakeGeminiServer() as s:
        yield s


def settings(server: FakeGeminiServer, max_attempts: int = 4, **over: Any):
    cfg = ApiModelConfig(name="gemini25pro", provider="gemini", model_id="gemini-2.5-pro",
                         api_key_env="VISPHY_TEST_GEMINI_KEY", base_url=server.url,
                         max_output_tokens=4096, timeout_s=10.0,
                         retries=RetriesConfig(max_attempts=max_attempts, base_delay_s=0.01,
                                               max_delay_s=0.05),
                         price=PriceConfig(1.25, 10.0, 0.31))
    for k, v in over.items():
        setattr(cfg, k, v)
    return OmegaConf.structured(cfg)


def request() -> ModelRequest:
    return ModelRequest(scene_id="s1", prompt=PROMPT, images=list(IMAGES), detection=None,
                        engine_name="p5", language="javascript",
                        output=OutputContract(5, 17, 512, 512))


def generate(server: FakeGeminiServer, **over: Any) -> ModelResponse:
    model = ApiModel(settings(server, **over))

    async def go() -> ModelResponse:
        try:
            return await model.agenerate(request())
        finally:
            await model.aclose()

    return asyncio.run(go())


def parts_of(req: Recorded) -> list[dict]:
    (content,) = req.json["contents"]
    assert content["role"] == "user"
    return content["parts"]


def inline(part: dict) -> tuple[str, bytes]:
    """(mime type, bytes) of an inline part. The SDK writes ``mime_type`` and URL-safe base64
    (``-_``); the API's JSON mapping accepts either spelling and either alphabet, so decode
    strictly in both (a lenient standard decode silently drops ``-`` and ``_``)."""
    data = part["inlineData"]
    mime = data.get("mimeType", data.get("mime_type"))
    encoded = data["data"].replace("-", "+").replace("_", "/")
    return mime, base64.b64decode(encoded, validate=True)


def assert_key_only_in_header(req: Recorded) -> None:
    assert req.headers.get("x-goog-api-key") == KEY
    assert "key" not in req.query
    assert KEY not in req.raw_url
    assert KEY.encode() not in req.body
    assert "authorization" not in req.headers


# --------------------------------------------------------------------------- the happy path

def test_request_wire_format_and_parsed_response(server: FakeGeminiServer) -> None:
    server.script = [ok("class Sim {}", {"input_tokens": 1200, "output_tokens": 800,
                                         "reasoning_tokens": 300, "cached_input_tokens": 200})]
    resp = generate(server)

    (req,) = server.requests
    assert req.method == "POST"
    assert "gemini-2.5-pro" in req.path and req.path.endswith(":generateContent")
    assert model_of(req) == "gemini-2.5-pro"
    assert_key_only_in_header(req)
    body = req.json
    assert body["generationConfig"]["maxOutputTokens"] == 4096
    assert "temperature" not in body["generationConfig"]  # None: the model's default
    parts = parts_of(req)
    assert parts[0] == {"text": PROMPT}
    assert [inline(p) for p in parts[1:]] == [("image/png", img.png) for img in IMAGES]

    assert resp.error is None and resp.error_kind is None
    assert resp.text == "class Sim {}"
    assert resp.finish_reason == "stop" and resp.refusal is None
    assert resp.model_id == "gemini-2.5-pro"
    assert resp.transport_attempts == 1
    assert resp.usage == {"input_tokens": 1200, "output_tokens": 1100,
                          "cached_input_tokens": 200, "reasoning_tokens": 300}
    expected = (1000 * 1.25 + 200 * 0.31 + 1100 * 10.0) / 1e6
    assert resp.cost_usd == pytest.approx(expected)
    assert KEY not in repr(resp.raw)
    assert resp.raw["finish_reason"] == "STOP"


def test_generation_settings_are_sent(server: FakeGeminiServer) -> None:
    resp = generate(server, temperature=0.0, seed=7, thinking_budget=2048)
    assert resp.error is None
    gen = server.requests[0].json["generationConfig"]
    assert gen["temperature"] == 0.0
    assert gen["seed"] == 7
    thinking = gen["thinkingConfig"]
    assert thinking.get("thinkingBudget", thinking.get("thinking_budget")) == 2048


def test_thought_parts_are_not_part_of_the_answer() -> None:
    class Thinking(FakeGeminiServer):
        def ok_body(self, req, text, usage):
            body = super().ok_body(req, text, usage)
            body["candidates"][0]["content"]["parts"].insert(
                0, {"text": "let me think...", "thought": True})
            return body

    with Thinking() as server:
        resp = generate(server)
    assert resp.text == "fake reply"


def test_video_part_is_sent_inline_as_mp4(server: FakeGeminiServer) -> None:
    clip = b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 4
    client = make_client(settings(server), KEY)

    async def go():
        try:
            return await client.complete([Part("text", text="describe"),
                                          Part("video", data=clip)], 256)
        finally:
            await client.aclose()

    completion = asyncio.run(go())
    assert completion.text == "fake reply"
    parts = parts_of(server.requests[0])
    assert parts[0] == {"text": "describe"}
    assert inline(parts[1]) == ("video/mp4", clip)
    assert_key_only_in_header(server.requests[0])


# --------------------------------------------------------------------------- retried faults

def test_429_with_retry_after_zero_then_ok(server: FakeGeminiServer) -> None:
    server.script = [status(429, {"Retry-After": "0"}), ok("done")]
    resp = generate(server)
    assert resp.error is None and resp.text == "done"
    assert server.count() == 2 and resp.transport_attempts == 2


def test_retry_after_is_waited_for(server: FakeGeminiServer) -> None:
    server.script = [status(429, {"Retry-After": "0.3"}), ok("done")]
    resp = generate(server)
    assert resp.text == "done" and resp.transport_attempts == 2
    first, second = server.requests
    assert second.time - first.time >= 0.28


def test_503_then_ok(server: FakeGeminiServer) -> None:
    server.script = [status(503), ok("after outage")]
    resp = generate(server)
    assert resp.text == "after outage" and server.count() == 2


def test_persistent_500_fails_as_server_after_max_attempts(server: FakeGeminiServer) -> None:
    server.default = lambda req: status(500)
    resp = generate(server, max_attempts=3)
    assert resp.error_kind == "server" and "500" in (resp.error or "")
    assert server.count() == 3 and resp.transport_attempts == 3


def test_client_timeout(server: FakeGeminiServer) -> None:
    server.default = lambda req: delay(3.0, ok("too late"))
    resp = generate(server, max_attempts=2, timeout_s=0.5)
    assert resp.error_kind == "timeout"
    assert server.count() == 2


def test_malformed_json_is_retried_then_fails(server: FakeGeminiServer) -> None:
    server.script = [malformed(), ok("recovered")]
    assert generate(server).text == "recovered"
    server.requests.clear()
    server.default = lambda req: malformed()
    resp = generate(server, max_attempts=3)
    assert resp.error_kind == "malformed" and server.count() == 3


def test_empty_reply_is_retried_then_fails(server: FakeGeminiServer) -> None:
    server.default = lambda req: empty()
    resp = generate(server, max_attempts=3)
    assert resp.error_kind == "empty" and server.count() == 3


def test_dropped_connection(server: FakeGeminiServer) -> None:
    server.default = lambda req: drop()
    resp = generate(server, max_attempts=2)
    assert resp.error_kind == "connection" and server.count() == 2


def test_connection_refused() -> None:
    dead = FakeGeminiServer().start()
    url = dead.url
    dead.stop()  # the port now refuses connections
    resp = generate(_Url(url), max_attempts=2)  # type: ignore[arg-type]
    assert resp.error_kind == "connection" and resp.transport_attempts == 2


class _Url:
    """Stands in for a server where only ``.url`` is needed."""

    def __init__(self, url: str):
        self.url = url


# --------------------------------------------------------------------------- final answers

def test_truncated_reply_is_a_success_with_length(server: FakeGeminiServer) -> None:
    server.script = [truncated("class Sim { step() {")]
    resp = generate(server)
    assert resp.error is None and resp.finish_reason == "length"
    assert resp.text == "class Sim { step() {" and server.count() == 1


def test_blocked_prompt_is_a_refusal(server: FakeGeminiServer) -> None:
    server.script = [refusal()]
    resp = generate(server)
    assert resp.error is None and resp.text == ""
    assert resp.finish_reason == "refusal" and "SAFETY" in (resp.refusal or "")
    assert server.count() == 1


def test_filtered_candidate_is_content_filter(server: FakeGeminiServer) -> None:
    server.script = [blocked_candidate("PROHIBITED_CONTENT")]
    resp = generate(server)
    assert resp.error is None and resp.finish_reason == "content_filter"
    assert "PROHIBITED_CONTENT" in (resp.refusal or "") and server.count() == 1


@pytest.mark.parametrize("code,kind", [(401, "auth"), (403, "auth"), (400, "bad_request"),
                                       (404, "bad_request")])
def test_unretryable_statuses_fail_at_once(server: FakeGeminiServer, code: int,
                                           kind: str) -> None:
    server.default = lambda req: status(code, message="API key not valid")
    resp = generate(server)
    assert resp.error_kind == kind and f"HTTP {code}" in (resp.error or "")
    assert server.count() == 1 and resp.transport_attempts == 1
    assert KEY not in (resp.error or "")


def test_sdk_retries_are_off(server: FakeGeminiServer) -> None:
    """One `complete` is one HTTP attempt, even on a status the SDK would retry by default."""
    client = make_client(settings(server), KEY)
    server.script = [status(503)]

    async def go() -> BaseException | None:
        try:
            await client.complete([Part("text", text="x")], 16)
        except Exception as exc:  # noqa: BLE001 - the point is which exception
            return exc
        finally:
            await client.aclose()
        return None

    exc = asyncio.run(go())
    assert type(exc).__name__ == "CallError" and exc.kind.value == "server"  # type: ignore
    assert server.count() == 1


def test_sdk_timeout_is_set_and_classified(server: FakeGeminiServer) -> None:
    """The SDK's own per-request timeout fires (``httpx2.ReadTimeout``), not only the caller's
    outer ``wait_for``, and comes back as a timeout."""
    client = make_client(settings(server, timeout_s=0.5), KEY)
    server.script = [delay(3.0, ok("too late"))]

    async def go() -> BaseException | None:
        try:
            await client.complete([Part("text", text="x")], 16)
        except Exception as exc:  # noqa: BLE001 - the point is which exception
            return exc
        finally:
            await client.aclose()
        return None

    exc = asyncio.run(go())
    assert type(exc).__name__ == "CallError" and exc.kind.value == "timeout"  # type: ignore
    assert "Timeout" in str(exc)
