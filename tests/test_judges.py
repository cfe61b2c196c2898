"""The judges end to end: `ApiJudge` -> `ApiCaller` -> the provider's official SDK -> HTTP -> the
matching fake server on loopback, configured from the shipped ``conf/judge/<name>.yaml``.

Each test checks what arrived at the server (model, the two clips or 2·k frames in order, the
prompt, temperature, where the key went) and the verdict the judge made of the reply: scores
parsed from fenced JSON, prose and "7/10"; out-of-range scores, no JSON, refusals, truncation and
persistent provider failures counted as invalid, never as numbers. Also: `videoscore2` says what
is missing instead of scoring, and the judge identity (the verdict cache key) follows the
settings that change a verdict and ignores transport settings.
"""

from __future__ import annotations

import asyncio
import base64
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from omegaconf import OmegaConf
from PIL import Image

from visphy_core.api.judge import JudgeInput, Verdict, uniform_indices
from visphy_core.calls.keys import MissingKey
from visphy_core.calls.prompts.build import judge_prompt
from visphy_core.infra.video import decode_video, encode_video
from visphy_plugins.judges import api_judges
from visphy_plugins.judges.api_judges import ApiJudge, ApiJudgeConfig
from visphy_plugins.judges.videoscore import (
    VideoScore2Judge,
    VideoScore2JudgeConfig,
    parse_scores,
    sample_indices,
    to_ten,
)
from visphy_plugins.testing.fake_anthropic import FakeAnthropicServer
from visphy_plugins.testing.fake_gemini import FakeGeminiServer, model_of
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.fake_server import (
    FakeProviderServer,
    Recorded,
    ok,
    refusal,
    status,
    truncated,
)

CONF = Path(__file__).resolve().parents[1] / "conf" / "judge"
N_FRAMES, FPS, SIZE = 17, 5.0, 64

#: judge -> (fake server class, base-URL suffix, key variable, key, header carrying the key)
JUDGES: dict[str, tuple[type[FakeProviderServer], str, str, str, str]] = {
    "gemini": (FakeGeminiServer, "", "GEMINI_API_KEY", "test-gemini-judge-5e1f", "x-goog-api-key"),
    "gpt_frames": (FakeOpenAIServer, "/v1", "OPENAI_API_KEY", "sk-test-judge-77a2",
                   "authorization"),
    "qwen_vl": (FakeOpenAIServer, "/compatible-mode/v1", "DASHSCOPE_API_KEY",
                "sk-dash-test-judge-09c4", "authorization"),
    "claude_frames": (FakeAnthropicServer, "", "ANTHROPIC_API_KEY", "sk-ant-test-judge-3b8d",
                      "x-api-key"),
}
VIDEO_JUDGES = ("gemini", "qwen_vl")
pytestmark = pytest.mark.filterwarnings(
    "ignore:The model 'claude-sonnet-4-5' is deprecated:DeprecationWarning")
FRAME_JUDGES = ("gpt_frames", "claude_frames")


# ----------------------------------------------------------------------------- clips and configs

def _square_clip(moving: bool) -> list[np.ndarray]:
    frames = []
    for t in range(N_FRAMES):
        frame = np.full((SIZE, SIZE, 3), 235, np.uint8)
        x = 4 + 2 * t if moving else 20
        frame[24:40, x:x + 16] = (200, 30, 30)
        frames.append(frame)
    return frames


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> tuple[Path, Path]:
    """(reference: a square moving right, generated: the square standing still)."""
    root = tmp_path_factory.mktemp("clips")
    ref = encode_video(_square_clip(moving=True), root / "reference.mp4", FPS)
    gen = encode_video(_square_clip(moving=False), root / "generated.mp4", FPS)
    return ref, gen


def judge_input(clips: tuple[Path, Path]) -> JudgeInput:
    return JudgeInput(scene_id="s1", dim="2d", reference_video=clips[0],
                      generated_video=clips[1], fps=FPS, n_frames=N_FRAMES)


@pytest.fixture(autouse=True)
def keys(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for _, _, var, key, _ in JUDGES.values():
        monkeypatch.setenv(var, key)
    for var in ("GOOGLE_API_KEY", "GOOGLE_GENAI_USE_VERTEXAI", "GOOGLE_GENAI_USE_ENTERPRISE",
                "GOOGLE_GENAI_API_VERSION", "OPENAI_BASE_URL", "ANTHROPIC_BASE_URL",
                "VISPHY_WEIGHTS"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("VISPHY_ENV_FILE", str(tmp_path / "no.env"))


def judge_cfg(name: str, base_url: str | None = None, max_attempts: int = 3, **over: Any):
    """The shipped YAML on its schema, pointed at a fake server with short retry delays."""
    yaml = OmegaConf.load(CONF / f"{name}.yaml")
    assert yaml.pop("defaults") == ["schema_api_judge"]
    cfg = OmegaConf.merge(OmegaConf.structured(ApiJudgeConfig), yaml)
    cfg.base_url = base_url
    cfg.timeout_s = 10.0
    cfg.retries.max_attempts = max_attempts
    cfg.retries.base_delay_s, cfg.retries.max_delay_s = 0.01, 0.02
    for k, v in over.items():
        OmegaConf.update(cfg, k, v)
    return cfg


@pytest.fixture(params=list(JUDGES))
def any_judge(request):
    """(judge name, running fake server, base URL) for each of the four API judges."""
    name = request.param
    server_cls, suffix = JUDGES[name][:2]
    with server_cls() as server:
        yield name, server, server.url + suffix


def run_judge(name: str, base_url: str, clips: tuple[Path, Path], **over: Any
              ) -> tuple[Verdict, ApiJudge]:
    judge = ApiJudge(judge_cfg(name, base_url, **over))

    async def go() -> Verdict:
        try:
            return await judge.ajudge(judge_input(clips))
        finally:
            await judge.aclose()

    return asyncio.run(go()), judge


# ----------------------------------------------------------------------------- the wire formats

def _b64(data: str) -> bytes:
    return base64.b64decode(data.replace("-", "+").replace("_", "/"), validate=True)


def _data_url(url: str) -> tuple[str, bytes]:
    head, data = url.split(",", 1)
    assert head.startswith("data:") and head.endswith(";base64")
    return head[5:-7], _b64(data)


def sent_parts(name: str, req: Recorded) -> list[tuple[str, Any]]:
    """The user message as [(kind, text or bytes)], kind text|image|video, in wire order."""
    body = req.json
    out: list[tuple[str, Any]] = []
    if name == "gemini":
        (content,) = body["contents"]
        assert content["role"] == "user"
        for p in content["parts"]:
            if "text" in p:
                out.append(("text", p["text"]))
            else:
                data = p["inlineData"]
                mime = data.get("mimeType", data.get("mime_type"))
                out.append(({"video/mp4": "video", "image/png": "image"}[mime],
                            _b64(data["data"])))
        return out
    (message,) = body["messages"]
    assert message["role"] == "user"
    for p in message["content"]:
        if p["type"] == "text":
            out.append(("text", p["text"]))
        elif p["type"] == "image_url":                       # OpenAI / DashScope
            mime, data = _data_url(p["image_url"]["url"])
            assert mime == "image/png"
            out.append(("image", data))
        elif p["type"] == "video_url":                       # DashScope (OpenAI-compatible)
            mime, data = _data_url(p["video_url"]["url"])
            assert mime == "video/mp4"
            out.append(("video", data))
        elif p["type"] == "image":                           # Anthropic
            assert p["source"]["type"] == "base64" and p["source"]["media_type"] == "image/png"
            out.append(("image", _b64(p["source"]["data"])))
        else:
            raise AssertionError(f"unexpected part {p['type']}")
    return out


def sent_model(name: str, req: Recorded) -> str:
    return model_of(req) if name == "gemini" else req.json["model"]


def sent_temperature(name: str, req: Recorded) -> Any:
    body = req.json
    if name == "gemini":
        return body.get("generationConfig", {}).get("temperature", "absent")
    return body.get("temperature", "absent")


def assert_key_only_in_header(name: str, req: Recorded) -> None:
    key, header = JUDGES[name][3], JUDGES[name][4]
    carrying = {h: v for h, v in req.headers.items() if key in v}
    allowed = [{header: f"Bearer {key}" if header == "authorization" else key}]
    if name == "claude_frames":  # newer anthropic SDKs send the key as a bearer token
        allowed.append({"authorization": f"Bearer {key}"})
    assert carrying in allowed
    assert key not in req.raw_url
    assert key.encode() not in req.body


def decode_png(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


FENCED = "Here is my verdict.\n```json\n{\"score\": 7, \"justification\": \"close\"}\n```\n"


# ----------------------------------------------------------------------------- video judges

@pytest.mark.parametrize("name", VIDEO_JUDGES)
def test_video_judge_sends_both_clips_reference_first(name, clips, tmp_path):
    server_cls, suffix = JUDGES[name][:2]
    with server_cls() as server:
        server.script = [ok(FENCED)]
        verdict, _ = run_judge(name, server.url + suffix, clips)
    (req,) = server.requests
    expected_model = {"gemini": "gemini-2.5-pro", "qwen_vl": "qwen3-vl-plus"}[name]
    assert sent_model(name, req) == expected_model
    if name == "qwen_vl":
        assert req.path == "/compatible-mode/v1/chat/completions"
        assert "max_tokens" in req.json and "max_completion_tokens" not in req.json
    assert_key_only_in_header(name, req)
    assert sent_temperature(name, req) == 0.0

    parts = sent_parts(name, req)
    text, version = judge_prompt("video")
    assert [k for k, _ in parts] == ["text", "video", "video"]
    assert parts[0][1] == text
    ref_bytes, gen_bytes = clips[0].read_bytes(), clips[1].read_bytes()
    assert ref_bytes != gen_bytes
    assert parts[1][1] == ref_bytes and parts[2][1] == gen_bytes   # reference first
    for i, (_, data) in enumerate(parts[1:]):
        path = tmp_path / f"sent{i}.mp4"
        path.write_bytes(data)
        frames, info = decode_video(path)
        assert len(frames) == N_FRAMES and info.fps == pytest.approx(FPS)

    assert verdict.valid and verdict.score == 7.0 and verdict.error is None
    assert verdict.justification == "close"
    assert verdict.judge_model == expected_model
    assert verdict.prompt_version == version and version.startswith("judge_video@")
    assert verdict.sampling == "video"
    assert verdict.transport_attempts == 1
    assert verdict.usage["input_tokens"] == 1200 and verdict.usage["output_tokens"] == 800
    price_in, price_out = {"gemini": (1.25, 10.0), "qwen_vl": (0.2, 1.6)}[name]
    assert verdict.cost_usd == pytest.approx((1200 * price_in + 800 * price_out) / 1e6)
    assert verdict.raw == FENCED


# ----------------------------------------------------------------------------- frame judges

@pytest.mark.parametrize("k", [8, 3])
@pytest.mark.parametrize("name", FRAME_JUDGES)
def test_frame_judge_sends_2k_frames_reference_first_in_time_order(name, k, clips):
    server_cls, suffix = JUDGES[name][:2]
    with server_cls() as server:
        server.script = [ok('{"score": "7/10", "justification": "static"}')]
        verdict, _ = run_judge(name, server.url + suffix, clips, frames=k)
    (req,) = server.requests
    expected_model = {"gpt_frames": "gpt-5", "claude_frames": "claude-sonnet-4-5"}[name]
    assert sent_model(name, req) == expected_model
    assert_key_only_in_header(name, req)
    # GPT-5 takes only its default temperature (not sent); Claude is asked for 0.
    assert sent_temperature(name, req) == {"gpt_frames": "absent", "claude_frames": 0.0}[name]

    parts = sent_parts(name, req)
    text, version = judge_prompt("frames", n_frames=k, duration_s=N_FRAMES / FPS)
    assert parts[0] == ("text", text)
    assert f"{k} frames each" in text
    images = [data for kind, data in parts[1:] if kind == "image"]
    assert len(parts) == 1 + 2 * k and len(images) == 2 * k
    idx = uniform_indices(N_FRAMES, k)
    assert len(idx) == k and idx[0] == 0 and idx[-1] == N_FRAMES - 1
    ref_frames, _ = decode_video(clips[0])
    gen_frames, _ = decode_video(clips[1])
    expected = [ref_frames[i] for i in idx] + [gen_frames[i] for i in idx]
    for got, want in zip(images, expected):
        assert np.array_equal(decode_png(got), want)
    # the reference's square moves right frame after frame; the generated one stands still
    assert not np.array_equal(decode_png(images[0]), decode_png(images[k - 1]))
    assert np.array_equal(decode_png(images[k]), decode_png(images[2 * k - 1]))

    assert verdict.valid and verdict.score == 7.0
    assert verdict.judge_model == expected_model
    assert verdict.prompt_version == version and version.startswith("judge_frames@")
    assert verdict.sampling == f"uniform:{k} frames per clip"


def test_a_video_for_a_provider_without_video_is_an_invalid_verdict(clips):
    with FakeAnthropicServer() as server:
        verdict, _ = run_judge("claude_frames", server.url, clips, input="video")
    assert server.requests == []
    assert not verdict.valid and verdict.score is None
    assert verdict.error_kind == "bad_request" and "video" in verdict.error


def test_an_unreadable_clip_is_an_invalid_verdict_without_a_call(any_judge, clips, tmp_path):
    name, server, base_url = any_judge
    judge = ApiJudge(judge_cfg(name, base_url))
    inp = JudgeInput(scene_id="s1", dim="2d", reference_video=clips[0],
                     generated_video=tmp_path / "missing.mp4", fps=FPS, n_frames=N_FRAMES)
    verdict = asyncio.run(judge.ajudge(inp))
    assert server.requests == []
    assert not verdict.valid and verdict.score is None
    assert verdict.error.startswith("cannot read the clips") and "missing.mp4" in verdict.error


# ----------------------------------------------------------------------------- reply parsing

@pytest.mark.parametrize("reply,score", [
    (FENCED, 7.0),
    ('I compared the clips carefully. {"score": 6, "justification": "late bounce"} Thanks.',
     6.0),
    ('{"score": "7/10", "justification": "ok"}', 7.0),
    ('{"score": 10, "justification": "identical"}', 10.0),
    ('{"score": 1, "justification": "nothing moves"}', 1.0),
])
def test_scores_are_parsed_from_every_judge(any_judge, clips, reply, score):
    name, server, base_url = any_judge
    server.script = [ok(reply)]
    verdict, _ = run_judge(name, base_url, clips)
    assert verdict.valid and verdict.score == score and verdict.error is None
    assert verdict.raw == reply


@pytest.mark.parametrize("behaviour,fragment", [
    (ok('{"score": 11, "justification": "too good"}'), "outside 1–10"),
    (ok('{"score": 0, "justification": "nothing"}'), "outside 1–10"),
    (ok("The reconstruction is decent, I would say seven."), "no JSON"),
    (ok('{"score": "seven", "justification": "words"}'), "not a number"),
    (refusal("I can't evaluate these videos."), "refused"),
    (truncated('{"score": 7, "justifica'), "truncated"),
])
def test_bad_replies_are_invalid_never_a_number(any_judge, clips, behaviour, fragment):
    name, server, base_url = any_judge
    server.script = [behaviour]
    verdict, _ = run_judge(name, base_url, clips)
    assert not verdict.valid and verdict.score is None
    assert fragment in verdict.error and "\n" not in verdict.error
    assert verdict.error_kind is None          # a reply, not a call failure
    assert verdict.transport_attempts == 1
    assert len(server.requests) == 1           # judged replies are not retried


def test_persistent_server_error_is_an_invalid_verdict_of_kind_server(any_judge, clips):
    name, server, base_url = any_judge
    server.default = lambda req: status(500, message="internal failure")
    verdict, _ = run_judge(name, base_url, clips, max_attempts=3)
    assert len(server.requests) == 3
    assert not verdict.valid and verdict.score is None
    assert verdict.error_kind == "server"
    assert verdict.error and "\n" not in verdict.error and "500" in verdict.error
    assert verdict.transport_attempts == 3
    assert verdict.cost_usd is None
    assert JUDGES[name][3] not in json.dumps(verdict.to_json())


def test_a_rate_limit_then_a_reply_is_retried(any_judge, clips):
    name, server, base_url = any_judge
    server.script = [status(429, {"Retry-After": "0"}), ok('{"score": 4}')]
    verdict, _ = run_judge(name, base_url, clips)
    assert verdict.valid and verdict.score == 4.0
    assert verdict.transport_attempts == 2 and len(server.requests) == 2


def test_a_missing_key_stops_before_any_call(monkeypatch):
    monkeypatch.delenv("GEMINI_API_KEY")
    judge = ApiJudge(judge_cfg("gemini", "http://127.0.0.1:9"))
    assert judge.needs_key == "GEMINI_API_KEY"
    with pytest.raises(MissingKey, match="GEMINI_API_KEY"):
        judge.check_ready()


# ----------------------------------------------------------------------------- identity

def test_identity_follows_what_changes_a_verdict_not_transport(monkeypatch):
    def ident(name: str = "gpt_frames", **over: Any) -> str:
        return ApiJudge(judge_cfg(name, **over)).identity()

    base = ident()
    payload = json.loads(base)
    assert "gpt_frames" in payload and "frames" in payload and 8 in payload
    assert any(isinstance(p, dict) and p.get("model_id") == "gpt-5" for p in payload)
    assert judge_prompt("frames")[1] in payload

    assert ident(model_id="gpt-5-mini") != base
    assert ident(frames=4) != base
    assert ident(max_output_tokens=4096) != base
    assert ident(reasoning_effort="low") != base
    assert ident(input="video") != base
    assert ident("claude_frames") != base
    # transport and accounting settings do not change a verdict
    assert ident(base_url="http://127.0.0.1:1/v1") == base
    assert ident(timeout_s=33.0) == base
    assert ident(max_attempts=9) == base
    assert ident(**{"price.input_usd_per_mtok": 99.0}) == base
    assert ident(**{"concurrency.maximum": 2}) == base
    # a video judge's identity does not depend on the (unused) frame count
    assert ident("gemini", frames=3) == ident("gemini")
    # a new judge-prompt version is a new identity
    real = api_judges.judge_prompt
    monkeypatch.setattr(api_judges, "judge_prompt",
                        lambda kind, *a, **k: (real(kind, *a, **k)[0], "judge_frames@999"))
    assert ident() != base


# ----------------------------------------------------------------------------- configs

def test_judge_configs_compose_one_or_several():
    from hydra import compose, initialize_config_module
    from hydra.core.global_hydra import GlobalHydra

    from visphy_core.api.registry import get_registry
    from visphy_core.config.check import check_values

    get_registry()
    GlobalHydra.instance().clear()
    try:
        with initialize_config_module(config_module="visphy_conf", version_base="1.3"):
            one = compose(config_name="config", overrides=["judge=gemini"])
            several = compose(config_name="config",
                              overrides=["judge=[gemini,gpt_frames,qwen_vl,claude_frames,"
                                         "videoscore2]"])
            none = compose(config_name="config")
    finally:
        GlobalHydra.instance().clear()
    assert list(one.judge) == ["gemini"] and one.judge.gemini.name == "gemini"
    assert one.judge.gemini.input == "video" and one.judge.gemini.model_id == "gemini-2.5-pro"
    assert set(several.judge) == {"gemini", "gpt_frames", "qwen_vl", "claude_frames",
                                  "videoscore2"}
    for entry, node in several.judge.items():
        assert node.name == entry
    assert several.judge.gpt_frames.input == "frames" and several.judge.gpt_frames.frames == 8
    assert several.judge.qwen_vl.api_key_env == "DASHSCOPE_API_KEY"
    assert several.judge.qwen_vl.max_tokens_param == "max_tokens"
    assert several.judge.videoscore2.weights_dir is None
    assert dict(none.judge) == {}
    check_values(several)


# ----------------------------------------------------------------------------- videoscore2

def vs2(**over: Any) -> VideoScore2Judge:
    cfg = OmegaConf.structured(VideoScore2JudgeConfig(name="videoscore2"))
    for k, v in over.items():
        cfg[k] = v
    return VideoScore2Judge(cfg)


def test_videoscore2_without_weights_says_what_is_missing(tmp_path, monkeypatch, clips):
    reason = vs2().unavailable_reason()
    assert reason and "$VISPHY_WEIGHTS" in reason and "weights_dir" in reason
    assert "TIGER-Lab/VideoScore2" in reason            # how to supply them
    import importlib.util
    for mod in ("torch", "transformers"):
        if importlib.util.find_spec(mod) is None:
            assert f"{mod} is not installed" in reason

    missing = tmp_path / "nowhere"
    assert f"{missing} does not exist" in vs2(weights_dir=str(missing)).unavailable_reason()

    monkeypatch.setenv("VISPHY_WEIGHTS", str(tmp_path))
    (tmp_path / "videoscore2").mkdir()
    reason = vs2().unavailable_reason()
    assert str(tmp_path / "videoscore2") in reason and "no config.json" in reason

    verdict = asyncio.run(vs2().ajudge(judge_input(clips)))
    assert not verdict.valid and verdict.score is None
    assert verdict.error.startswith("unavailable: ")


def test_videoscore2_output_mapping():
    reply = ("The ball falls smoothly... visual quality: 4;\ntext-to-video alignment: 3,\n"
             "physical/common-sense consistency: 2")
    assert parse_scores(reply) == {"visual_quality": 4, "text_alignment": 3,
                                   "physical_consistency": 2}
    assert parse_scores("no scores here") is None
    assert [to_ten(s) for s in (1, 2, 3, 4, 5)] == [1.0, 3.25, 5.5, 7.75, 10.0]
    idx = sample_indices(N_FRAMES, FPS, 2.0)
    assert len(idx) % 2 == 0 and len(idx) >= 4 and idx[0] == 0 and idx[-1] == N_FRAMES - 1


def test_videoscore2_verdict_from_a_reply(monkeypatch, tmp_path, clips):
    """The verdict made of a VideoScore2 answer (inference itself needs torch and weights)."""
    (tmp_path / "config.json").write_text("{}")
    judge = vs2(weights_dir=str(tmp_path), aggregate="mean")
    monkeypatch.setattr(judge, "unavailable_reason", lambda: None)
    monkeypatch.setattr(judge, "_infer", lambda path: "Smooth. visual quality: 5; "
                        "text-to-video alignment: 4, physical/common-sense consistency: 3")
    verdict = asyncio.run(judge.ajudge(judge_input(clips)))
    assert verdict.valid and verdict.score == pytest.approx(to_ten(4.0))
    raw = json.loads(verdict.raw)
    assert raw["dimensions"] == {"visual_quality": 5, "text_alignment": 4,
                                 "physical_consistency": 3}
    judge.cfg.aggregate = "physical"
    assert asyncio.run(judge.ajudge(judge_input(clips))).score == pytest.approx(5.5)
    monkeypatch.setattr(judge, "_infer", lambda path: "visual quality: 9; text-to-video "
                        "alignment: 4, physical/common-sense consistency: 3")
    bad = asyncio.run(judge.ajudge(judge_input(clips)))
    assert not bad.valid and bad.score is None and "outside 1–5" in bad.error
    assert vs2(weights_dir=str(tmp_path)).identity() != vs2().identity()
    assert vs2(infer_fps=4.0).identity() != vs2().identity()


def _tiny_qwen25vl(path: Path) -> None:
    """A randomly initialised, tiny Qwen2.5-VL (VideoScore2's architecture and processor)."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers
    from transformers import (
        Qwen2_5_VLConfig,
        Qwen2_5_VLForConditionalGeneration,
        Qwen2_5_VLProcessor,
        Qwen2TokenizerFast,
        Qwen2VLImageProcessor,
        Qwen2VLVideoProcessor,
    )

    special = ["<|endoftext|>", "<|im_start|>", "<|im_end|>", "<|vision_start|>",
               "<|vision_end|>", "<|image_pad|>", "<|video_pad|>"]
    bpe = Tokenizer(models.BPE())
    bpe.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    bpe.decoder = decoders.ByteLevel()
    bpe.train_from_iterator(["visual quality: 3; text-to-video alignment: 4, physical/common-"
                             "sense consistency: 2"] * 4, trainers.BpeTrainer(
        vocab_size=400, special_tokens=special,
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet()))
    chat = ("{% for m in messages %}<|im_start|>{{ m['role'] }}\n{% for c in m['content'] %}"
            "{% if c['type'] == 'video' %}<|vision_start|><|video_pad|><|vision_end|>"
            "{% else %}{{ c['text'] }}{% endif %}{% endfor %}<|im_end|>\n{% endfor %}"
            "{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}")
    tok = Qwen2TokenizerFast(tokenizer_object=bpe, eos_token="<|im_end|>",
                             pad_token="<|endoftext|>")
    ids = {t: tok.convert_tokens_to_ids(t) for t in special}
    cfg = Qwen2_5_VLConfig(
        text_config=dict(vocab_size=len(tok), hidden_size=64, intermediate_size=128,
                         num_hidden_layers=1, num_attention_heads=2, num_key_value_heads=1,
                         rope_scaling={"type": "mrope", "mrope_section": [4, 6, 6]},
                         eos_token_id=ids["<|im_end|>"], pad_token_id=ids["<|endoftext|>"]),
        vision_config=dict(depth=1, hidden_size=32, num_heads=2, intermediate_size=64,
                           out_hidden_size=64, fullatt_block_indexes=[0]),
        image_token_id=ids["<|image_pad|>"], video_token_id=ids["<|video_pad|>"],
        vision_start_token_id=ids["<|vision_start|>"], eos_token_id=ids["<|im_end|>"],
        pad_token_id=ids["<|endoftext|>"])
    Qwen2_5_VLForConditionalGeneration(cfg).save_pretrained(path)
    Qwen2_5_VLProcessor(image_processor=Qwen2VLImageProcessor(), tokenizer=tok,
                        video_processor=Qwen2VLVideoProcessor(),
                        chat_template=chat).save_pretrained(path)


def test_videoscore2_runs_a_local_qwen25vl_end_to_end(tmp_path, clips):
    """The real loading and inference path on a tiny random model of VideoScore2's
    architecture (where torch, torchvision and transformers are installed): its babble has no
    scores, so the verdict is invalid and says so, never a number."""
    for mod in ("torch", "torchvision", "transformers"):
        pytest.importorskip(mod)
    weights = tmp_path / "videoscore2"
    _tiny_qwen25vl(weights)
    judge = vs2(weights_dir=str(weights), max_new_tokens=16, dtype="float32", device="cpu")
    assert judge.unavailable_reason() is None
    answer = judge._infer(clips[1])
    assert isinstance(answer, str)
    verdict = asyncio.run(judge.ajudge(judge_input(clips)))
    assert verdict.error_kind is None, verdict.error
    assert json.loads(verdict.raw)["reply"] == answer          # greedy: reproducible
    assert not verdict.valid and verdict.score is None
    assert "no VideoScore2 scores" in verdict.error
