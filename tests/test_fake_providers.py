"""The bundled fake provider servers (`visphy_plugins.testing`) as a user meets them offline: a
run on any engine gets a program in that engine's language (here the scene's own reference
program, the scene told by its first key frame) and renders it as the model's; the fakes list
their models and refuse an unknown model id or a wrong URL path with 404, as the real services
do; `serve` prints commands whose interpreter exists. Real SDKs over loopback, real CLI runs."""

from __future__ import annotations

import json
import os
import shlex
from pathlib import Path

import anthropic
import openai
import pytest
from google import genai
from google.genai import errors as genai_errors
from google.genai import types as genai_types

from conftest import run_cli
from visphy_plugins.engines.blender import find_blender_python
from visphy_plugins.testing import serve
from visphy_plugins.testing.fake_anthropic import FakeAnthropicServer
from visphy_plugins.testing.fake_gemini import FakeGeminiServer
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.replies import SceneBook, engine_of, program_reply

KEY = "fake-key"


def _env(var: str) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    env[var] = KEY
    return env


def _rows(home: Path) -> list[dict]:
    (run_dir,) = sorted((home / "runs").iterdir())[-1:]
    return [json.loads(ln) for ln in (run_dir / "results.jsonl").read_text().splitlines()
            if ln.strip().endswith("}")]


def _run(home: Path, engine: str, model: str, base_url: str, var: str) -> list[dict]:
    run_cli(f"engine={engine}", f"model={model}", f"model.base_url={base_url}", "dataset=mini",
            "dataset.limit=1", "tracking=none", "run.progress=false", home=home, env=_env(var))
    rows = _rows(home)
    assert len(rows) == 1
    return rows


def _model_program(row: dict) -> None:
    assert row["model_success"] is True or row["model_success"] == 1, row
    assert not row.get("fallback"), row


@pytest.fixture
def servers(mini_scenes):
    started = serve.start_servers(SceneBook(mini_scenes))
    yield started
    for server in started.values():
        server.stop()


@pytest.mark.manim
def test_claude_on_manim_renders_the_scenes_reference_program(servers, visphy_home):
    (row,) = _run(visphy_home, "manim", "claude", servers["anthropic"].url, "ANTHROPIC_API_KEY")
    _model_program(row)
    (req,) = servers["anthropic"].requests
    assert engine_of(req.json) == "manim"


@pytest.mark.blender
@pytest.mark.skipif(find_blender_python() is None, reason="Blender venv missing")
def test_gpt41_on_blender_renders_the_scenes_reference_program(servers, visphy_home):
    (row,) = _run(visphy_home, "blender", "gpt41", servers["openai"].url + "/v1",
                  "OPENAI_API_KEY")
    _model_program(row)


@pytest.mark.browser
def test_gemini_on_p5_renders_the_scenes_reference_program(servers, visphy_home):
    (row,) = _run(visphy_home, "p5", "gemini25pro", servers["gemini"].url, "GEMINI_API_KEY")
    _model_program(row)


def test_program_reply_is_in_the_engines_language(mini_scenes):
    from visphy_core.calls.prompts.build import PromptSettings, build_prompt
    from visphy_plugins.testing.replies import _engine

    scene = mini_scenes[0]
    for name, fence in (("manim", "```python"), ("blender", "```python"), ("p5", "```html"),
                        ("svg", "```html"), ("threejs", "```html")):
        engine = _engine(name)
        text, _, _ = build_prompt(scene, engine.instructions(scene.dim), engine.language,
                                  PromptSettings())
        body = {"messages": [{"role": "user", "content": [{"type": "text", "text": text}]}]}
        assert engine_of(body) == name
        generic = program_reply(body)
        assert fence in generic and "```json" in generic
        engine.validate(engine.extract(generic))


def test_model_lists_and_refusals_through_the_sdks():
    with FakeOpenAIServer() as oai, FakeAnthropicServer() as ant, FakeGeminiServer() as gem:
        client = openai.OpenAI(api_key=KEY, base_url=oai.url + "/v1", max_retries=0)
        assert {"gpt-5", "gpt-4.1", "qwen3-vl-plus"} <= {m.id for m in client.models.list()}
        with pytest.raises(openai.NotFoundError) as exc:
            client.chat.completions.create(model="gpt-5-typo", messages=[
                {"role": "user", "content": "hi"}])
        assert exc.value.code == "model_not_found"
        wrong = openai.OpenAI(api_key=KEY, base_url=oai.url + "/api/v1", max_retries=0)
        with pytest.raises(openai.NotFoundError):
            wrong.chat.completions.create(model="gpt-5", messages=[
                {"role": "user", "content": "hi"}])
        assert client.chat.completions.create(model="gpt-5", messages=[
            {"role": "user", "content": "hi"}]).choices[0].message.content

        ac = anthropic.Anthropic(api_key=KEY, base_url=ant.url, max_retries=0)
        assert [m.id for m in ac.models.list()] == ["claude-sonnet-4-5"]
        with pytest.raises(anthropic.NotFoundError) as aexc:
            ac.messages.create(model="claude-typo", max_tokens=10,
                               messages=[{"role": "user", "content": "hi"}])
        assert aexc.value.body["error"]["type"] == "not_found_error"
        wrong_a = anthropic.Anthropic(api_key=KEY, base_url=ant.url + "/v1", max_retries=0)
        with pytest.raises(anthropic.NotFoundError):
            wrong_a.messages.create(model="claude-sonnet-4-5", max_tokens=10,
                                    messages=[{"role": "user", "content": "hi"}])

        gc = genai.Client(api_key=KEY, http_options=genai_types.HttpOptions(base_url=gem.url))
        names = {m.name for m in gc.models.list()}
        assert {"models/gemini-2.5-pro", "models/gemini-3-pro-preview"} <= names
        with pytest.raises(genai_errors.ClientError) as gexc:
            gc.models.generate_content(model="gemini-typo", contents="hi")
        assert gexc.value.code == 404 and gexc.value.status == "NOT_FOUND"
        # nothing refused reached the script
        assert oai.count() == 1 and ant.count() == 0 and gem.count() == 0
        assert {code for _, code in oai.gated} == {200, 404}


def test_preflight_refuses_an_unknown_id_in_one_line(tmp_path):
    with FakeOpenAIServer(models=("Qwen/Qwen2.5-VL-7B-Instruct",)) as server:
        proc = run_cli("model=openai_compat", f"model.base_url={server.url}/v1",
                       "model.model_id=qwen-typo", "dataset=tiny", "tracking=none",
                       home=tmp_path / "home", check=False)
        assert server.count() == 0
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-2000:]
    assert "model.model_id=qwen-typo is not served" in lines[0]
    assert "Qwen/Qwen2.5-VL-7B-Instruct" in lines[0]


def test_serve_prints_commands_that_run_as_printed(tmp_path, capsys, monkeypatch):
    import signal
    import threading

    monkeypatch.setattr(signal, "signal", lambda *a: None)
    monkeypatch.setattr(threading.Event, "wait", lambda self, *a: True)
    assert serve.main(["--json", str(tmp_path / "s.json")]) == 0
    printed = capsys.readouterr().out
    commands = [ln.strip() for ln in printed.splitlines() if ln.strip().startswith("env ")]
    assert len(commands) == 6
    info = json.loads((tmp_path / "s.json").read_text())
    for cmd in commands:
        words = shlex.split(cmd)[1:]
        python = next(w for w in words if "=" not in w)
        assert Path(python).is_absolute() and os.access(python, os.X_OK), cmd
        assert words[words.index(python) + 1:][:2] == ["-m", "visphy_core"]
    compat = next(c for c in commands if "model=openai_compat" in c)
    assert f"model.model_id={serve.COMPAT_MODEL}" in compat
    assert info["model_overrides"]["openai_compat"] in compat
    assert any("engine=manim model=claude" in c for c in commands)
