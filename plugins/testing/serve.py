"""Serve the fake providers on loopback until interrupted, and print how to point visphy at them.

``python -m visphy_plugins.testing.serve`` starts the fake OpenAI (also DashScope's compatible
mode), Anthropic and Gemini servers on 127.0.0.1 and prints the environment and the overrides
that send every API judge (and model) there, e.g. to run the judge-replacement study offline::

    python -m visphy_plugins.testing.serve              # in one shell
    env GEMINI_API_KEY=fake ... python -m visphy_core -m experiment=judge_replacement ...

What the servers answer: a judge request (its prompt asks for a ``justification``) gets a
well-formed verdict whose score (1-10) is a hash of the request, so it is deterministic per judge
and clip pair but **not a judgement**; any other request gets a well-formed reply with a
browser program (`replies.reply`), so ``model=gpt5 model.base_url=...`` runs on the browser
engines. ``--json PATH`` also writes the URLs, environment and overrides as JSON (for scripts and
tests); keys are fake values set only for the command printed, never in your shell.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shlex
import signal
import sys
import threading
from pathlib import Path

from visphy_plugins.testing.fake_anthropic import FakeAnthropicServer
from visphy_plugins.testing.fake_gemini import FakeGeminiServer
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.fake_server import DEFAULT_USAGE, Behaviour, Recorded, ok
from visphy_plugins.testing.replies import reply

#: judge key -> (provider, URL suffix, key variable), as in conf/judge/.
JUDGES = {"gemini": ("gemini", "", "GEMINI_API_KEY"),
          "gpt_frames": ("openai", "/v1", "OPENAI_API_KEY"),
          "qwen_vl": ("openai", "/compatible-mode/v1", "DASHSCOPE_API_KEY"),
          "claude_frames": ("anthropic", "", "ANTHROPIC_API_KEY")}
#: model config -> (provider, URL suffix, key variable), as in conf/model/.
MODELS = {"gpt5": ("openai", "/v1", "OPENAI_API_KEY"),
          "gpt41": ("openai", "/v1", "OPENAI_API_KEY"),
          "qwen3vlplus": ("openai", "/compatible-mode/v1", "DASHSCOPE_API_KEY"),
          "claude": ("anthropic", "", "ANTHROPIC_API_KEY"),
          "gemini3pro": ("gemini", "", "GEMINI_API_KEY"),
          "gemini25pro": ("gemini", "", "GEMINI_API_KEY")}


def answer(req: Recorded) -> Behaviour:
    """A verdict for a judge request, a program reply for anything else."""
    if b"justification" in req.body:
        score = 1 + int(hashlib.sha256(req.body).hexdigest(), 16) % 10
        verdict = {"score": score, "justification": "A fake verdict from the loopback server: "
                   "a hash of the request, deterministic, not a judgement."}
        return ok(json.dumps(verdict), dict(DEFAULT_USAGE))
    return ok(reply("html"), dict(DEFAULT_USAGE))


def start_servers() -> dict[str, object]:
    servers = {"openai": FakeOpenAIServer(default=answer),
               "anthropic": FakeAnthropicServer(default=answer),
               "gemini": FakeGeminiServer(default=answer)}
    for server in servers.values():
        server.start()
    return servers


def connection(urls: dict[str, str]) -> dict[str, object]:
    """The environment and overrides that point visphy's API judges and models at ``urls``."""
    env = {var: f"fake-{var.lower().replace('_', '-')}"
           for _, _, var in (*JUDGES.values(), *MODELS.values())}
    judges = [f"judge.{key}.base_url={urls[p]}{suffix}" for key, (p, suffix, _) in JUDGES.items()]
    models = {name: f"model.base_url={urls[p]}{suffix}" for name, (p, suffix, _) in MODELS.items()}
    return {"urls": urls, "env": env, "judge_overrides": judges, "model_overrides": models}


def command(info: dict, overrides: list[str]) -> str:
    env = " ".join(f"{k}={v}" for k, v in sorted(info["env"].items()))
    return f"env {env} python -m visphy_core " + " ".join(shlex.quote(o) for o in overrides)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m visphy_plugins.testing.serve",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, help="also write URLs, env and overrides here")
    args = parser.parse_args(argv)
    servers = start_servers()
    info = connection({name: server.url for name, server in servers.items()})
    if args.json:
        args.json.write_text(json.dumps(info, indent=2) + "\n")
    print("fake providers on loopback (Ctrl-C stops them):")
    for name, url in info["urls"].items():
        print(f"  {name:9s} {url}")
    print("\nthe judge-replacement study against them:")
    print("  " + command(info, ["-m", "experiment=judge_replacement", *info["judge_overrides"]]))
    print("\na model against them (browser engines), e.g. gpt5:")
    print("  " + command(info, ["model=gpt5", info["model_overrides"]["gpt5"]]), flush=True)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    for server in servers.values():
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
