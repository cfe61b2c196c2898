"""Serve the fake providers on loopback until interrupted, and print how to point visphy at them.

``.venv/bin/python -m visphy_plugins.testing.serve`` starts the fake OpenAI (also DashScope's
compatible mode), Anthropic and Gemini servers on 127.0.0.1 and prints the environment and the
overrides that send every API judge and model there, as commands that run as printed (this
interpreter's full path, the venv need not be activated), e.g. to run the judge-replacement study
offline::

    .venv/bin/python -m visphy_plugins.testing.serve              # in one shell
    env GEMINI_API_KEY=fake ... /…/.venv/bin/python -m visphy_core -m experiment=... ...

What the servers answer: a judge request (its prompt asks for a ``justification``) gets a
well-formed verdict whose score (1-10) is a hash of the request, so it is deterministic per judge
and clip pair but **not a judgement**; a program request gets a well-formed reply in the language
of the engine its prompt asks for (`replies.program_reply`): a generic falling-ball program of
that engine, or, with ``--benchmark DIR``, the scene's own reference program (the scene told by
its first key frame). Like the real services they list their models (the ids of ``conf/model``
and ``conf/judge``, plus `COMPAT_MODEL` for ``model=openai_compat``) and refuse other ids and
wrong URL paths with 404. ``--json PATH`` also writes the URLs, environment and overrides as JSON
(for scripts and tests); keys are fake values set only for the command printed, never in your
shell.
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
from visphy_plugins.testing.fake_server import DEFAULT_USAGE, Behaviour, Recorded, known_models, ok
from visphy_plugins.testing.replies import SceneBook, program_reply

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
#: The model the fake OpenAI server also serves for ``model=openai_compat`` (a local server's).
COMPAT_MODEL = "Qwen/Qwen2.5-VL-7B-Instruct"


def answer(req: Recorded, book: SceneBook | None = None) -> Behaviour:
    """A verdict for a judge request, a program reply in the asked engine's language for
    anything else (the scene's reference program when ``book`` knows the scene)."""
    if b"justification" in req.body:
        score = 1 + int(hashlib.sha256(req.body).hexdigest(), 16) % 10
        verdict = {"score": score, "justification": "A fake verdict from the loopback server: "
                   "a hash of the request, deterministic, not a judgement."}
        return ok(json.dumps(verdict), dict(DEFAULT_USAGE))
    return ok(program_reply(req.json, book), dict(DEFAULT_USAGE))


def start_servers(book: SceneBook | None = None) -> dict[str, object]:
    """The three fakes, started; ``book``: scenes whose reference programs they answer."""
    def default(req: Recorded) -> Behaviour:
        return answer(req, book)

    servers = {"openai": FakeOpenAIServer(default=default,
                                          models=(*known_models("openai"), COMPAT_MODEL)),
               "anthropic": FakeAnthropicServer(default=default),
               "gemini": FakeGeminiServer(default=default)}
    for server in servers.values():
        server.start()
    return servers


def connection(urls: dict[str, str]) -> dict[str, object]:
    """The environment and overrides that point visphy's API judges and models at ``urls``."""
    env = {var: f"fake-{var.lower().replace('_', '-')}"
           for _, _, var in (*JUDGES.values(), *MODELS.values())}
    judges = [f"judge.{key}.base_url={urls[p]}{suffix}" for key, (p, suffix, _) in JUDGES.items()]
    models = {name: f"model.base_url={urls[p]}{suffix}" for name, (p, suffix, _) in MODELS.items()}
    models["openai_compat"] = f"model.base_url={urls['openai']}/v1"
    return {"urls": urls, "env": env, "judge_overrides": judges, "model_overrides": models,
            "openai_compat_model_id": COMPAT_MODEL, "python": sys.executable}


def command(info: dict, overrides: list[str]) -> str:
    """The command line, with this interpreter's full path: it runs as printed, from any shell
    (``env`` sets the fake keys for it alone)."""
    env = " ".join(f"{k}={v}" for k, v in sorted(info["env"].items()))
    return (f"env {env} {shlex.quote(info.get('python') or sys.executable)} -m visphy_core "
            + " ".join(shlex.quote(o) for o in overrides))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m visphy_plugins.testing.serve",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, help="also write URLs, env and overrides here")
    parser.add_argument("--benchmark", type=Path, help="a generated benchmark's directory: "
                        "answer its scenes with their reference programs")
    parser.add_argument("--split", default="mini", help="the --benchmark split (default mini)")
    args = parser.parse_args(argv)
    book = None
    if args.benchmark:
        from visphy_plugins.datasets.visphybench.loader import load_generated

        book = SceneBook(load_generated(args.benchmark, split=args.split))
    servers = start_servers(book)
    info = connection({name: server.url for name, server in servers.items()})
    if args.json:
        args.json.write_text(json.dumps(info, indent=2) + "\n")
    print("fake providers on loopback (Ctrl-C stops them):")
    for name, url in info["urls"].items():
        print(f"  {name:9s} {url}")
    print("\nthe judge-replacement study against them:")
    print("  " + command(info, ["-m", "experiment=judge_replacement", *info["judge_overrides"]]))
    print("\na model against them (any engine: the reply is in the engine's language), e.g.:")
    for name, engine in (("gpt5", "threejs"), ("claude", "manim"), ("gpt41", "blender"),
                         ("gemini25pro", "p5"), ("openai_compat", "svg")):
        extra = [f"model.model_id={COMPAT_MODEL}"] if name == "openai_compat" else []
        print("  " + command(info, [f"engine={engine}", f"model={name}",
                                    info["model_overrides"][name], *extra]))
    print(flush=True)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    for server in servers.values():
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
