"""Every API model through the real CLI and its real SDK against a loopback fake server: what
the provider received (model, both key frames, max tokens, no key in URLs or files, no ground
truth), the parsed replies, cost and tokens in the summary; a missing key; a restarted run that
repeats no call; the cost cap; replay reproducing a run."""

from __future__ import annotations

import base64
import io
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from conftest import FAST_METRICS, REPO, run_cli
from visphy_plugins.datasets.tiny import make_tiny_dataset
from visphy_plugins.testing.fake_anthropic import FakeAnthropicServer
from visphy_plugins.testing.fake_gemini import FakeGeminiServer
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.fake_server import delay, ok
from visphy_plugins.testing.replies import reply

pytestmark = pytest.mark.browser

SECRET = "sk-visphy-test-9f8e7d6c5b4a"

#: model config -> (fake server class, base-url suffix, key variable)
PROVIDERS = {
    "gpt5": (FakeOpenAIServer, "/v1", "OPENAI_API_KEY"),
    "claude": (FakeAnthropicServer, "", "ANTHROPIC_API_KEY"),
    "gemini25pro": (FakeGeminiServer, "", "GEMINI_API_KEY"),
    "qwen3vlplus": (FakeOpenAIServer, "/compatible-mode/v1", "DASHSCOPE_API_KEY"),
    "openai_compat": (FakeOpenAIServer, "/v1", "OPENAI_COMPAT_API_KEY"),
}


def _b64(data: str) -> bytes:
    data = data.replace("-", "+").replace("_", "/")
    return base64.b64decode(data + "=" * (-len(data) % 4))


def images_sent(body: dict) -> list[bytes]:
    """The images of one request, in order, in any of the three wire formats."""
    out = []
    for msg in body.get("messages", []):
        for part in msg.get("content", []) if isinstance(msg.get("content"), list) else []:
            if part.get("type") == "image_url":
                out.append(_b64(part["image_url"]["url"].split(",", 1)[1]))
            elif part.get("type") == "image":
                out.append(_b64(part["source"]["data"]))
    for content in body.get("contents", []):
        for part in content.get("parts", []):
            inline = part.get("inlineData") or part.get("inline_data")
            if inline and (inline.get("mimeType") or inline.get("mime_type")) == "image/png":
                out.append(_b64(inline["data"]))
    return out


def text_sent(body: dict) -> str:
    return json.dumps(body)


def max_tokens_sent(body: dict) -> int | None:
    for key in ("max_completion_tokens", "max_tokens"):
        if key in body:
            return body[key]
    cfg = body.get("generationConfig") or body.get("generation_config") or {}
    return cfg.get("maxOutputTokens") or cfg.get("max_output_tokens")


def model_sent(req) -> str:
    body = req.json or {}
    return body.get("model") or req.path.split("/models/")[-1].split(":")[0]


def _decode_png(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def _server(name: str):
    cls, suffix, key = PROVIDERS[name]
    # the fakes serve the configs' model ids; a local server also serves "served-model"
    extra = {"models": ("served-model",)} if name == "openai_compat" else {}
    server = cls(default=lambda req: ok(reply("html"), {"input_tokens": 1500,
                                                       "output_tokens": 700}), **extra)
    return server, suffix, key


def _env(key: str, **extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    env[key] = SECRET
    env.update(extra)
    return env


def _summary(home: Path) -> dict:
    (run_dir,) = sorted((home / "runs").iterdir())[-1:]
    return json.loads((run_dir / "summary.json").read_text())


def _no_secret_anywhere(home: Path) -> None:
    for path in home.rglob("*"):
        if path.is_file() and path.stat().st_size < 50_000_000:
            assert SECRET.encode() not in path.read_bytes(), f"key leaked into {path}"


@pytest.mark.parametrize("name", list(PROVIDERS))
def test_a_full_scene_through_each_provider_sdk(name, visphy_home, mini_scenes):
    """The mini split's first two scenes (generated: they have a spec and a trajectory, so a
    leak of ground truth would show) through the model's real SDK."""
    server, suffix, key = _server(name)
    with server:
        extra = ["model.model_id=served-model"] if name == "openai_compat" else []
        run_cli(f"model={name}", f"model.base_url={server.url}{suffix}", "engine=threejs",
                "dataset=mini", "dataset.limit=2", "tracking=none", "run.progress=false",
                "model.retries.base_delay_s=0.01", *extra,
                home=visphy_home, env=_env(key))
        requests = list(server.requests)
    assert len(requests) == 2
    summary = _summary(visphy_home)
    assert summary["model_success"] == 2, summary["failures"]
    usage = summary["usage"]["generate"]
    assert usage["calls"] == 2 and usage["input_tokens"] == 3000
    assert usage["output_tokens"] == 1400 and usage["cost_usd"] >= 0
    if name != "openai_compat":
        assert usage["cost_usd"] > 0
    scenes = {s.scene_id: s for s in mini_scenes}
    expected = [scenes[sid] for sid in sorted(scenes)[:2]]
    matched = []
    for req in requests:  # calls run concurrently: pair each request with its scene by image
        body = req.json
        assert model_sent(req) in ("served-model", server_model(name))
        assert max_tokens_sent(body)
        assert SECRET not in req.raw_url and SECRET.encode() not in req.body
        assert any(SECRET in v for v in req.headers.values())
        imgs = [_decode_png(b) for b in images_sent(body)]
        assert len(imgs) == 2
        scene = next(sc for sc in expected if np.array_equal(imgs[0], sc.key_frame(1)))
        matched.append(scene.scene_id)
        assert np.array_equal(imgs[0], scene.key_frame(1))
        assert np.array_equal(imgs[1], scene.key_frame(10))
        text = text_sent(body)
        for leak in ("ground_truth", "digest_sha256", "trajectories/", ".npz",
                     scene.spec["digest_sha256"]):
            assert leak not in text
    assert sorted(matched) == [sc.scene_id for sc in expected]
    _no_secret_anywhere(visphy_home)


def server_model(name: str) -> str:
    return {"gpt5": "gpt-5", "claude": "claude-sonnet-4-5", "gemini25pro": "gemini-2.5-pro",
            "qwen3vlplus": "qwen3-vl-plus"}.get(name, "")


def test_forecast_only_and_no_detection_send_less(visphy_home, mini_scenes):
    server, suffix, key = _server("claude")
    with server:
        run_cli("model=claude", f"model.base_url={server.url}", "dataset=mini",
                "dataset.limit=1", "tracking=none", "run.progress=false",
                "prompt.forecast_only=true", "prompt.detection=false",
                home=visphy_home, env=_env(key))
        (req,) = server.requests
    imgs = images_sent(req.json)
    assert len(imgs) == 1 and np.array_equal(_decode_png(imgs[0]), mini_scenes[0].key_frame(1))
    assert "Object detections" not in text_sent(req.json)


def test_missing_key_is_one_line_before_any_work(tmp_path):
    env = {k: v for k, v in os.environ.items() if "API_KEY" not in k}
    proc = subprocess.run([sys.executable, "-m", "visphy_core", "model=claude", "engine=manim"],
                          cwd=tmp_path, env=dict(env, VISPHY_HOME=str(tmp_path / "home")),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "ANTHROPIC_API_KEY" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "home").exists()  # no dataset built, no run directory


def test_key_from_dot_env_file(tmp_path):
    root = make_tiny_dataset(tmp_path / "data", 1)
    home = tmp_path / "home"
    server, suffix, key = _server("claude")
    env = {k: v for k, v in os.environ.items() if "API_KEY" not in k}
    (tmp_path / "keys.env").write_text(f"ANTHROPIC_API_KEY={SECRET}\n")
    with server:
        run_cli("model=claude", f"model.base_url={server.url}", "dataset=original",
                f"dataset.root={root}", "tracking=none", "run.progress=false",
                home=home, env=dict(env, VISPHY_ENV_FILE=str(tmp_path / "keys.env")))
        assert server.count() == 1
    _no_secret_anywhere(home)


@pytest.mark.manim
def test_claude_with_manim_runs_end_to_end_against_the_fake(tmp_path):
    root = make_tiny_dataset(tmp_path / "data", 1)
    server = FakeAnthropicServer(default=lambda req: ok(reply("python")))
    with server:
        run_cli("model=claude", "engine=manim", f"model.base_url={server.url}",
                "dataset=original", f"dataset.root={root}", "tracking=none",
                "run.progress=false", home=tmp_path / "home", env=_env("ANTHROPIC_API_KEY"))
    summary = _summary(tmp_path / "home")
    assert summary["model_success"] == 1 and summary["usage"]["generate"]["calls"] == 1


def _rows(home: Path) -> int:
    return sum(len([ln for ln in p.read_text().splitlines() if ln.endswith("}")])
               for p in (home / "runs").glob("*/results.jsonl")) if (home / "runs").is_dir() else 0


@pytest.mark.slow
def test_an_interrupted_20_scene_run_repeats_no_call(tmp_path):
    root = make_tiny_dataset(tmp_path / "data", 20)
    home = tmp_path / "home"
    server = FakeOpenAIServer(default=lambda req: delay(0.4, ok(reply("html"))))
    args = ["model=gpt41", "engine=threejs", "dataset=original", f"dataset.root={root}",
            "tracking=none", "run.progress=false", "run.prefetch=4", *FAST_METRICS]
    with server:
        args.append(f"model.base_url={server.url}/v1")
        env = dict(_env("OPENAI_API_KEY"), VISPHY_HOME=str(home))
        proc = subprocess.Popen([sys.executable, "-m", "visphy_core", *args], cwd=REPO, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            end = time.monotonic() + 300
            while _rows(home) < 8:
                assert proc.poll() is None and time.monotonic() < end
                time.sleep(0.05)
            proc.send_signal(signal.SIGINT)
            out, _ = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
        assert proc.returncode == 130, out[-2000:]
        done = _rows(home)
        assert 8 <= done < 20
        calls_before = server.count()
        assert calls_before >= done
        run_cli(*args, home=home, env=_env("OPENAI_API_KEY"))
        assert server.count() == 20  # every scene asked exactly once, across both processes
    summary = _summary(home)
    assert summary["status"] == "finished" and summary["n_scenes"] == 20
    assert summary["model_success"] == 20
    assert summary["usage"]["generate"]["calls"] == 20


def test_cost_cap_stops_new_calls_and_says_so(tmp_path):
    root = make_tiny_dataset(tmp_path / "data", 6)
    home = tmp_path / "home"
    server = FakeOpenAIServer(default=lambda req: ok(reply("html"), {"input_tokens": 100_000,
                                                                    "output_tokens": 10_000}))
    # gpt41: 100k in * $2/M + 10k out * $8/M = $0.28 per call; a $0.50 cap allows 2 calls.
    args = ["model=gpt41", "engine=threejs", "dataset=original", f"dataset.root={root}",
            "tracking=none", "run.progress=false", "run.prefetch=0", "run.cost_cap_usd=0.5"]
    with server:
        proc = run_cli(*args, f"model.base_url={server.url}/v1", home=home,
                       env=_env("OPENAI_API_KEY"))
        assert server.count() == 2
    summary = _summary(home)
    assert summary["status"] == "cost_cap" and summary["n_scenes"] == 2
    assert len(summary["cost_cap"]["not_run"]) == 4
    assert summary["usage"]["generate"]["cost_usd"] == pytest.approx(0.56)
    assert "cost cap" in proc.stderr


def test_replay_of_a_run_reproduces_its_rows(tmp_path):
    root = make_tiny_dataset(tmp_path / "data", 3)
    home = tmp_path / "home"
    server = FakeOpenAIServer(default=lambda req: ok(reply("html")))
    with server:
        run_cli("model=gpt41", f"model.base_url={server.url}/v1", "dataset=original",
                f"dataset.root={root}", "tracking=none", "run.progress=false",
                home=home, env=_env("OPENAI_API_KEY"))
    (first,) = list((home / "runs").iterdir())
    run_cli("model=replay", f"model.source={first}", "dataset=original", f"dataset.root={root}",
            "tracking=none", "run.progress=false", home=home, env=_env("OPENAI_API_KEY"))
    (second,) = [p for p in (home / "runs").iterdir() if p != first]
    keep = ("scene_id", "model_success", "attempts", "failure_class", "frame_digests", "flags",
            "spec_valid", "prompt_version")

    def rows(d):
        out = {}
        for line in (d / "results.jsonl").read_text().splitlines():
            r = json.loads(line)
            out[r["scene_id"]] = {k: v for k, v in r.items()
                                  if k in keep or k.startswith("score_")}
        return out

    assert rows(first) == rows(second)
    assert _summary(home)["usage"]["generate"]["cost_usd"] == 0


def test_two_judges_from_the_command_line_score_every_scene(tmp_path):
    """`judge=[gemini,gpt_frames]` composes, passes the config check and calls each judge once
    per scene; their scores and each stage's usage land in the rows, the summary and MLflow."""
    root = make_tiny_dataset(tmp_path / "data", 2)
    home = tmp_path / "home"
    gem = FakeGeminiServer(default=lambda req: ok('{"score": 8, "justification": "same"}'))
    def openai(req):  # the model's calls get a program, the frame judge's (16 images) a verdict
        if len(images_sent(req.json)) > 2:
            return ok('Verdict: {"score": 6, "justification": "close"}')
        return ok(reply("html"), {"input_tokens": 1000, "output_tokens": 500})

    oai = FakeOpenAIServer(default=openai)
    env = _env("GEMINI_API_KEY", OPENAI_API_KEY=SECRET)
    with gem, oai:
        run_cli("model=gpt41", f"model.base_url={oai.url}/v1", "engine=threejs",
                "dataset=original", f"dataset.root={root}", "run.progress=false",
                "judge=[gemini,gpt_frames]", f"judge.gemini.base_url={gem.url}",
                f"judge.gpt_frames.base_url={oai.url}/v1", home=home, env=env)
        assert gem.count() == 2 and oai.count() == 4   # 2 programs + 2 frame verdicts
    summary = _summary(home)
    judges = summary["judges"]
    assert judges["gemini"]["mean"] == 8 and judges["gpt_frames"]["mean"] == 6
    assert summary["usage"]["judge"]["calls"] == 4
    (run_dir,) = list((home / "runs").iterdir())
    rows = [json.loads(x) for x in (run_dir / "results.jsonl").read_text().splitlines()]
    verdicts = [(r["score_judge_gemini"], r["score_judge_gpt_frames"]) for r in rows]
    assert verdicts == [(8, 6), (8, 6)]
    with sqlite3.connect(home / "mlflow.db") as con:
        metrics = dict(con.execute("select key, value from latest_metrics").fetchall())
        tags = dict(con.execute("select key, value from tags").fetchall())
    for stage in ("generate", "judge"):
        for key in ("calls", "input_tokens", "output_tokens", "cost_usd"):
            assert metrics[f"usage.{stage}.{key}"] == pytest.approx(summary["usage"][stage][key])
    assert metrics["usage.generate.calls"] == 2 and metrics["usage.generate.cost_usd"] > 0
    assert metrics["judge.gemini.n_valid"] == 2 and metrics["judge.gpt_frames.n_invalid"] == 0
    # each stage's wall seconds: in every row, summed in the summary, logged to MLflow
    stages = summary["stage_seconds"]
    for name in ("model_latency_s", "render_wall_s", "scoring_wall_s", "judge_wall_s"):
        # both scenes got the same program: the second render is a cache hit, not counted
        values = [r[name] for r in rows if not (name == "render_wall_s" and r["render_cached"])]
        assert all(v is not None and v > 0 for v in values) and values, name
        assert stages[name]["n"] == len(values)
        assert stages[name]["total"] == pytest.approx(sum(values), abs=2e-3)
        assert metrics[f"seconds.{name}"] == pytest.approx(stages[name]["total"])
        assert metrics[f"seconds.{name}.per_scene"] == pytest.approx(stages[name]["mean"])
    assert tags["visphy.prompt_version"] == ",".join(summary["prompt_versions"])
    _no_secret_anywhere(home)
