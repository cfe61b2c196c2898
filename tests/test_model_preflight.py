"""The pre-flight of an API model (`visphy_plugins.providers.preflight`): an OpenAI-compatible
server that is not there, or does not serve ``model.model_id``, is one line and exit status 2
before any scene; a local server needs no key. Against a fake OpenAI-compatible server on
loopback that lists its models (``GET /v1/models``) as vLLM, Ollama and llama.cpp do."""

from __future__ import annotations

import socket

import pytest

from conftest import run_cli
from visphy_core.api.errors import UserError
from visphy_core.api.model import ModelRequest, OutputContract
from visphy_core.api.registry import get_registry
from visphy_core.config.check import compose
from visphy_plugins.providers.preflight import is_local
from visphy_plugins.testing.fake_openai import FakeOpenAIServer

SERVED = ("Qwen/Qwen2.5-VL-7B-Instruct", "llava:13b")


class ListingServer(FakeOpenAIServer):
    """The fake Chat Completions server serving (and listing at ``GET /v1/models``) the models
    of a local OpenAI-compatible server."""

    def __init__(self, **kwargs):
        super().__init__(models=SERVED, **kwargs)


def chat_calls(server: FakeOpenAIServer) -> int:
    return server.count(lambda r: r.path.endswith("/chat/completions"))


def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def no_key(monkeypatch):
    monkeypatch.delenv("OPENAI_COMPAT_API_KEY", raising=False)
    monkeypatch.setenv("VISPHY_ENV_FILE", "/nonexistent/.env")


def _error_line(proc) -> str:
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr[-3000:]
    return lines[0]


def test_a_missing_model_id_is_one_line_before_any_scene(tmp_path, no_key):
    home = tmp_path / "home"
    with ListingServer() as server:
        proc = run_cli("model=openai_compat", f"model.base_url={server.url}/v1",
                       "dataset=tiny", "tracking=none", home=home, check=False)
        line = _error_line(proc)
        assert chat_calls(server) == 0
        assert "model.model_id=" in line and f"{server.url}/v1" in line
    assert all(mid in line for mid in SERVED)  # what to set it to
    assert not (home / "runs").exists()


def test_the_http_clients_request_lines_stay_out_of_the_output(tmp_path, no_key):
    """httpx logs every request at INFO ("HTTP Request: GET .../models ..."), google-genai its
    "AFC is enabled" line; under Hydra's stdout logging they would interleave with the progress
    bars and the one error line, one per call of a 209-scene run."""
    with ListingServer() as server:
        proc = run_cli("model=openai_compat", f"model.base_url={server.url}/v1",
                       "dataset=tiny", "tracking=none", home=tmp_path / "home", check=False)
        _error_line(proc)
        # the request was made (a model listing is kept apart from the scripted requests)
        assert sum(r.path.endswith("/models") for r, _ in server.gated) == 1
    assert "HTTP Request" not in proc.stdout + proc.stderr, proc.stdout[-2000:]


def test_a_model_id_the_server_does_not_serve_is_one_line(tmp_path, no_key):
    home = tmp_path / "home"
    with ListingServer() as server:
        proc = run_cli("model=openai_compat", f"model.base_url={server.url}/v1",
                       "model.model_id=qwen-typo", "dataset=tiny", "tracking=none",
                       home=home, check=False)
        line = _error_line(proc)
        assert chat_calls(server) == 0
    assert "model.model_id=qwen-typo is not served" in line and SERVED[0] in line
    assert not (home / "runs").exists()


def test_no_server_listening_is_one_line_naming_the_url(tmp_path, no_key):
    home = tmp_path / "home"
    url = f"http://127.0.0.1:{closed_port()}/v1"
    proc = run_cli("model=openai_compat", f"model.base_url={url}", "model.model_id=m",
                   "dataset=tiny", "tracking=none", home=home, check=False)
    line = _error_line(proc)
    assert f"no server answers at {url}" in line and "model.base_url=" in line
    assert not (home / "runs").exists()


def _model(*overrides: str):
    cfg = compose(["model=openai_compat", *overrides])
    return get_registry().get("models", str(cfg.model.name))(cfg.model)


def test_a_good_local_setup_proceeds_without_a_key(no_key):
    with ListingServer() as server:
        model = _model(f"model.base_url={server.url}/v1", f"model.model_id={SERVED[1]}")
        assert model.needs_key is None
        model.check_ready()  # lists the models, finds the id
        response = model.generate(ModelRequest(
            scene_id="s1", prompt="hello", images=[], detection=None, engine_name="p5",
            language="javascript", output=OutputContract(5, 17, 512, 512)))
        assert response.error is None and response.text == "fake reply"
        (call,) = [r for r in server.requests if r.path.endswith("/chat/completions")]
        assert call.json["model"] == SERVED[1]
        assert call.headers["authorization"] == "Bearer none"


def test_a_server_that_lists_no_models_is_taken_at_its_word(no_key):
    with FakeOpenAIServer(models=None) as server:  # GET /models: 404
        _model(f"model.base_url={server.url}/v1", "model.model_id=anything").check_ready()


@pytest.mark.parametrize("suffix", ["", "/v1/chat/completions", "/v1/models/"])
def test_a_base_url_off_the_api_root_names_the_right_one(no_key, suffix):
    """``GET {base_url}/models`` is 404 (no ``/v1``, or a pasted endpoint path): the URL that
    lists the models is named, before any call."""
    with ListingServer() as server:
        with pytest.raises(UserError) as info:
            _model(f"model.base_url={server.url}{suffix}",
                   f"model.model_id={SERVED[0]}").check_ready()
        assert chat_calls(server) == 0
        root = f"{server.url}/v1"
    message = str(info.value)
    assert message.endswith(f"set model.base_url={root}"), message
    assert "HTTP 404" in message and "\n" not in message


def test_the_api_roots_tried_after_a_404():
    from visphy_plugins.providers.preflight import api_roots

    assert api_roots("http://h:8000") == ["http://h:8000/v1"]
    assert api_roots("http://h:8000/v1/chat/completions") == ["http://h:8000/v1"]
    assert api_roots("http://h/compatible-mode/v1") == []  # already a /v1 root: none other
    assert api_roots("http://h/api/chat/completions?x=1") == ["http://h/api", "http://h/api/v1"]


def test_a_remote_endpoint_still_needs_its_key(no_key):
    model = _model("model.base_url=https://api.example.com/v1", "model.model_id=m")
    assert model.needs_key == "OPENAI_COMPAT_API_KEY"
    with pytest.raises(UserError, match=r"needs the API key in \$OPENAI_COMPAT_API_KEY"):
        model.check_ready()  # before any connection


@pytest.mark.parametrize("url, local", [
    ("http://localhost:8000/v1", True), ("http://127.0.0.1:11434/v1", True),
    ("http://[::1]:8080/v1", True), ("http://192.168.1.20:8000/v1", True),
    ("http://10.0.0.5/v1", True), ("http://gpu-box:8000/v1", True),
    ("http://gpu-box.local:8000/v1", True), ("https://api.openai.com/v1", False),
    ("https://dashscope-intl.aliyuncs.com/compatible-mode/v1", False), (None, False),
    ("https://8.8.8.8/v1", False)])
def test_which_endpoints_are_local(url, local):
    assert is_local(url) is local


def test_an_api_judge_has_the_same_pre_flight(tmp_path, monkeypatch):
    """A judge on an OpenAI-compatible server (DashScope's ``qwen_vl``, or a local one) is asked
    the same way before any scene: an id the server does not serve is one line, naming the
    judge; a local server needs no key and the run goes on."""
    monkeypatch.delenv("DASHSCOPE_API_KEY", raising=False)
    monkeypatch.setenv("VISPHY_ENV_FILE", "/nonexistent/.env")
    with ListingServer() as server:
        proc = run_cli("model=static", "judge=qwen_vl", f"judge.qwen_vl.base_url={server.url}/v1",
                       "dataset=tiny", "dataset.limit=1", "tracking=none",
                       home=tmp_path / "home", check=False)
        line = _error_line(proc)
        assert "judge=qwen_vl" in line and "qwen3-vl-plus" in line and SERVED[0] in line
        assert chat_calls(server) == 0
        run_cli("model=static", "judge=qwen_vl", f"judge.qwen_vl.base_url={server.url}/v1",
                f"judge.qwen_vl.model_id={SERVED[0]}", "dataset=tiny", "dataset.limit=1",
                "tracking=none", home=tmp_path / "home")
        assert chat_calls(server) == 1  # the one verdict, sent with no key
        (call,) = [r for r in server.requests if r.path.endswith("/chat/completions")]
        assert call.headers.get("authorization", call.headers.get("Authorization")) == \
            "Bearer none"
