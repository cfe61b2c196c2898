"""Every command in README.md runs, in the README's order, on one fresh VISPHY_HOME.

A command is a line of a ```bash block or an inline code span that starts with ``make `` or
``.venv/bin/``. Each is run as written with *tiny settings* added, so the whole file stays cheap:

* a run (``visphy model=… dataset=…``, ``-m experiment=…``) gets the ``mini`` split cut to one
  scene, the two cheap metrics and no tracking; an API model is pointed at a loopback fake of its
  provider (the real SDK, the provider's wire format; a fake key in the variable the README
  names). A study is cut to one job.
* ``make run`` runs its real recipe without the install step (``make -o setup``): CI's own
  ``make test`` has just installed everything; ``make test`` is checked with ``make -n`` (it is
  the command running this test).
* a server (``make ui``, ``mkdocs serve``) must answer HTTP on loopback, then is stopped.
* paths under ``visphy-out/`` are the test's home; ``<run directory>``-style placeholders are the
  newest run.

A README command this file does not know how to run fails the test: a new command in the README
needs its way of running here, so the README cannot promise a command nobody ran.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from conftest import FAST_METRICS, REPO, SUBCOMMANDS
from visphy_plugins.testing.serve import MODELS, start_servers

pytestmark = [pytest.mark.browser, pytest.mark.slow]

README = REPO / "README.md"
VENV_BIN = Path(sys.executable).parent
#: tiny settings added to every run
TINY = ("dataset.limit=1", "tracking=none", *FAST_METRICS)
#: a dataset the README names -> the split a test run uses instead
DATASETS = {"visphybench": "mini", "visphybench_test": "mini", "mini": "mini"}
#: placeholders a README command may hold -> what stands for them here
PLACEHOLDERS = ("<run directory>", "<run>", "<run_dir>")
#: API model -> (fake server, URL suffix, key variable); video models have their own fakes
#: (the fake-provider launcher's table, plus a local server that needs no key and the two video
#: models)
API_MODELS = {**MODELS, "openai_compat": ("openai", "/v1", None),
              "veo": ("veo", "", "GEMINI_API_KEY"), "sora": ("sora", "/v1", "OPENAI_API_KEY")}


def readme_commands(text: str) -> list[str]:
    """The commands of a README, in order (a line's trailing ``# comment`` dropped)."""
    found: list[tuple[int, str]] = []
    for block in re.finditer(r"^```(?:bash|sh|shell)\n(.*?)^```", text, re.S | re.M):
        for i, line in enumerate(block.group(1).splitlines()):
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line and not line.startswith("#"):
                found.append((block.start() + i, line))
    prose = re.sub(r"^```.*?^```", lambda m: " " * len(m.group(0)), text, flags=re.S | re.M)
    for span in re.finditer(r"`([^`\n]+)`", prose):
        code = span.group(1).strip()
        if code.startswith(("make ", ".venv/bin/")) or code == "make":
            found.append((span.start(), code))
    seen, out = set(), []
    for _, cmd in sorted(found):
        same = re.sub(r"^\.venv/bin/python -m visphy_core\b", ".venv/bin/visphy", cmd)
        if same not in seen:
            seen.add(same)
            out.append(cmd)
    return out


def test_the_extractor_finds_blocks_and_inline_commands():
    text = ("Run `make run` first.\n\n```bash\nmake test   # all tests\n# a comment\n"
            ".venv/bin/visphy --help\n```\n\n| a | `.venv/bin/visphy model=claude` |\n"
            "```text\nnot a command\n```\nand `engine=p5` is an override, not a command.\n")
    assert readme_commands(text) == ["make run", "make test", ".venv/bin/visphy --help",
                                     ".venv/bin/visphy model=claude"]
    twice = ("`make run` and `.venv/bin/python -m visphy_core`, then `make run` and "
             "`.venv/bin/visphy`")
    assert readme_commands(twice) == ["make run", ".venv/bin/python -m visphy_core"]


def test_the_readme_has_commands_to_run():
    commands = readme_commands(README.read_text())
    assert "make run" in commands and "make test" in commands
    assert any(" model=" in c for c in commands), "no command evaluating a model"


# ------------------------------------------------------------------------------ running them
@dataclass
class Home:
    root: Path
    servers: dict
    runs_done: list[Path] = field(default_factory=list)

    def newest_run(self) -> Path:
        runs = sorted((self.root / "runs").iterdir(), key=lambda p: p.stat().st_mtime)
        return runs[-1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serves(url: str, proc: subprocess.Popen, timeout: float = 90.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.poll() is None:
        try:
            with urllib.request.urlopen(url, timeout=2) as resp:
                return resp.status == 200
        except OSError:
            time.sleep(0.5)
    return False


def _stop(proc: subprocess.Popen) -> str:
    """Stop a server's process group; what it printed."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return proc.stdout.read().decode(errors="replace")[-3000:] if proc.stdout else ""


def _check_serves(argv: list[str], url: str, env: dict | None = None) -> None:
    proc = subprocess.Popen(argv, cwd=REPO, start_new_session=True, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    served = False
    try:
        served = _serves(url, proc)
    finally:
        printed = _stop(proc)
    assert served, f"{' '.join(argv)} did not serve {url}:\n{printed}"


def _env(home: Home, extra: dict | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    env.update(VISPHY_HOME=str(home.root), VISPHY_ENV_FILE=str(home.root / "no.env"))
    env.update(extra or {})
    return env


def _local_paths(args: list[str], home: Home) -> list[str]:
    out = []
    for arg in args:
        for ph in PLACEHOLDERS:
            if ph in arg:
                arg = arg.replace(ph, home.newest_run().name)
        if "<" in arg and ">" in arg:
            raise AssertionError(f"README placeholder this test cannot fill: {arg}")
        arg = re.sub(r"(^|=)visphy-out(/|$)", lambda m: m.group(1) + str(home.root) + m.group(2),
                     arg)
        out.append(arg)
    return out


def _as_test_run(args: list[str], home: Home) -> tuple[list[str], dict]:
    """A run's overrides with the tiny settings, and the environment it needs."""
    args = _local_paths(args, home)
    out, env, model = [], {}, "oracle"
    for arg in args:
        key, _, value = arg.partition("=")
        if key == "dataset":
            assert value in DATASETS, f"a README dataset this test does not know: {value}"
            arg = f"dataset={DATASETS[value]}"
        elif key == "model":
            model = value
        elif key == "model.base_url":
            continue  # a local server the README names: the fake stands in for it
        out.append(arg)
    if "-m" in out or "--multirun" in out:  # a study: one job (its sweep set on the command line)
        out += [f"model={model}", "engine=threejs", "dataset=mini"]
    if model in API_MODELS:
        provider, suffix, key = API_MODELS[model]
        out.append(f"model.base_url={home.servers[provider].url}{suffix}")
        out += ["model.retries.base_delay_s=0.01"]
        if model in ("veo", "sora"):
            out.append("model.poll_interval_s=0")
        if key:
            env[key] = "fake-readme-key"
    return out + list(TINY), env


def run_readme_command(cmd: str, home: Home) -> str:
    """Run one README command here; returns what it printed (stdout)."""
    tokens = shlex.split(cmd)
    if tokens[0] == "make":
        target, rest = (tokens[1] if len(tokens) > 1 else ""), tokens[2:]
        if target == "test":
            dry = subprocess.run(["make", "-n", *tokens[1:]], cwd=REPO, capture_output=True,
                                 text=True, check=True)
            assert "pytest" in dry.stdout, dry.stdout
            return dry.stdout
        if target == "run":
            given = " ".join(a.partition("=")[2] for a in rest if a.startswith("ARGS="))
            given = "" if given.strip() in ("", "...") else given
            tiny = [a for a in TINY if a != "tracking=none"]  # the main job is tracked
            argv = ["make", "-o", "setup", "run", f"ARGS={given} {' '.join(tiny)}".strip()]
            proc = subprocess.run(argv, cwd=REPO, env=_env(home), capture_output=True,
                                  text=True, timeout=600)
            assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
            home.runs_done.append(home.newest_run())
            return proc.stdout
        if target == "ui":
            port = _free_port()
            _check_serves(["make", "ui"], f"http://127.0.0.1:{port}/",
                          _env(home, {"MLFLOW_PORT": str(port)}))
            return ""
        raise AssertionError(f"a README make target this test does not run: {cmd}")
    if tokens[0] == ".venv/bin/mkdocs" and tokens[1:2] == ["serve"]:
        port = _free_port()
        _check_serves([str(VENV_BIN / "mkdocs"), *tokens[1:], "-a", f"127.0.0.1:{port}"],
                      f"http://127.0.0.1:{port}/")
        return ""
    if tokens[0] == ".venv/bin/visphy":
        args = tokens[1:]
    elif tokens[:3] == [".venv/bin/python", "-m", "visphy_core"]:
        args = tokens[3:]
    else:
        raise AssertionError(f"a README command this test does not know how to run: {cmd}")
    program = [sys.executable, "-m", "visphy_core"]
    is_run = not args or (args[0] not in (*SUBCOMMANDS, "run") and not args[0].startswith("--")
                          ) or (args[0] == "run" and "--help" not in args)
    if is_run:
        args = args[1:] if args and args[0] == "run" else args
        args, extra = _as_test_run(args, home)
    else:
        args, extra = _local_paths(args, home), {}
    proc = subprocess.run([*program, *args], cwd=REPO, env=_env(home, extra),
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, (f"{cmd}\n -> {args}\n" + proc.stdout[-3000:]
                                  + proc.stderr[-3000:])
    if is_run and "-m" not in args:
        run = home.newest_run()
        summary = json.loads((run / "summary.json").read_text())
        assert summary["n_scenes"] == 1 and summary["model_success"] == 1, summary
        home.runs_done.append(run)
    return proc.stdout


@pytest.fixture(scope="module")
def servers():
    from visphy_plugins.testing.fake_sora import FakeSoraServer
    from visphy_plugins.testing.fake_veo import FakeVeoServer

    started = start_servers()  # OpenAI, Anthropic, Gemini: as `testing.serve` runs them
    for name, server in (("veo", FakeVeoServer(polls_before_done=0)),
                         ("sora", FakeSoraServer(polls_before_done=0))):
        server.start()
        started[name] = server
    yield started
    for server in started.values():
        server.stop()


@pytest.mark.timeout(1800)
def test_every_readme_command_runs_on_a_fresh_home(tmp_path, mini_root, servers):
    import shutil

    root = tmp_path / "home"
    shutil.copytree(mini_root, root / "data" / mini_root.name)  # the benchmark, not a run
    home = Home(root, servers)
    commands = readme_commands(README.read_text())
    ran = []
    for cmd in commands:
        run_readme_command(cmd, home)
        ran.append(cmd)
    assert ran == commands
    n_runs = sum(1 for c in commands if " model=" in f" {c}" and " -m " not in f" {c} ")
    assert len(home.runs_done) >= n_runs, (home.runs_done, commands)
