"""The process sandbox shared by the Python engines: environment, limits, network, work dir."""

from __future__ import annotations

import json
import os
import shutil
import socket
import sys
import tempfile
import time
from pathlib import Path

import pytest

from visphy_core.sandbox.process import (MAX_OUTPUT_BYTES, Limits, child_env,
                                         network_isolation_available, run_sandboxed,
                                         unprivileged_uid)

PY = sys.executable


def py(code: str) -> list[str]:
    return [PY, "-s", "-B", "-c", code]


def _alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            return not any(line.startswith("State:") and "Z" in line.split()[1] for line in fh)
    except FileNotFoundError:
        return False


def test_environment_is_scrubbed(tmp_path, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-parent-secret")
    monkeypatch.setenv("VISPHY_SOMETHING", "parent-only")
    res = run_sandboxed(py("import json, os; print(json.dumps(dict(os.environ)))"), tmp_path,
                        Limits(wall_s=30),
                        env_extra={"FOO": "bar", "MY_SECRET_TOKEN": "t", "DB_PASSWORD": "p"})
    assert res.returncode == 0, res.stderr
    env = json.loads(res.stdout)
    assert "sk-parent-secret" not in res.stdout
    assert "OPENAI_API_KEY" not in env and "VISPHY_SOMETHING" not in env
    assert "MY_SECRET_TOKEN" not in env and "DB_PASSWORD" not in env  # even via env_extra
    assert env["FOO"] == "bar"
    assert env["TZ"] == "UTC" and env["PYTHONHASHSEED"] == "0"
    assert set(env) <= {"PATH", "LANG", "LC_ALL", "TZ", "HOME", "TMPDIR", "PYTHONHASHSEED", "FOO",
                        "LC_CTYPE"}  # LC_CTYPE: Python's own C-locale coercion may add it


def test_secret_passes_only_when_named_explicitly(tmp_path):
    env = child_env(tmp_path, {"HF_TOKEN": "x", "API_KEY": "y"}, allow_secret_env=["HF_TOKEN"])
    assert env["HF_TOKEN"] == "x" and "API_KEY" not in env


def test_workdir_is_cwd_and_home(tmp_path):
    work = tmp_path / "work"
    code = ("import json, os; print(json.dumps([os.getcwd(), os.environ['HOME'], "
            "os.environ['TMPDIR'], os.path.isdir(os.environ['TMPDIR'])]))")
    res = run_sandboxed(py(code), work, Limits(wall_s=30))
    assert res.returncode == 0, res.stderr
    cwd, home, tmpdir, tmp_exists = json.loads(res.stdout)
    assert Path(cwd) == work.resolve() == Path(home) == res.workdir
    assert Path(tmpdir) == work.resolve() / "tmp" and tmp_exists


def test_wall_timeout_kills_loop_and_children(tmp_path):
    code = ("import subprocess, sys\n"
            "p = subprocess.Popen(['sleep', '300'])\n"
            "open('child.pid', 'w').write(str(p.pid))\n"
            "while True: pass\n")
    start = time.monotonic()
    res = run_sandboxed(py(code), tmp_path, Limits(wall_s=2, cpu_s=60))
    assert time.monotonic() - start < 15
    assert res.timed_out and res.limit_hit == "wall" and res.returncode is None
    assert 1.9 <= res.wall_s < 10
    child = int((tmp_path / "child.pid").read_text())
    deadline = time.monotonic() + 5
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(child), "the sandboxed program's child survived the wall-clock kill"


def test_background_children_die_with_the_program(tmp_path):
    code = ("import subprocess\n"
            "p = subprocess.Popen(['sleep', '300'])\n"
            "open('child.pid', 'w').write(str(p.pid))\n")
    res = run_sandboxed(py(code), tmp_path, Limits(wall_s=30))
    assert res.returncode == 0 and not res.timed_out
    child = int((tmp_path / "child.pid").read_text())
    deadline = time.monotonic() + 5
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(child)


def test_memory_limit_stops_a_10_gb_allocation(tmp_path):
    res = run_sandboxed(py("x = bytearray(10 * 1024 ** 3); print('allocated')"), tmp_path,
                        Limits(wall_s=60, memory_mb=1024))
    assert res.returncode not in (0, None)
    assert res.limit_hit == "memory", res.stderr
    assert "allocated" not in res.stdout


def test_file_size_limit(tmp_path):
    code = "open('big.bin', 'wb').write(b'x' * (3 << 20)); print('wrote')"
    res = run_sandboxed(py(code), tmp_path, Limits(wall_s=30, file_size_mb=1))
    assert res.returncode != 0 and res.limit_hit == "file_size", res.stderr
    assert (tmp_path / "big.bin").stat().st_size <= 1 << 20


def test_cpu_limit(tmp_path):
    res = run_sandboxed(py("while True: pass"), tmp_path, Limits(wall_s=30, cpu_s=1))
    assert res.limit_hit == "cpu" and not res.timed_out and res.returncode not in (0, None)


def test_output_is_capped(tmp_path):
    res = run_sandboxed(py("import sys; sys.stdout.write('a' * (8 << 20)); print('END')"),
                        tmp_path, Limits(wall_s=30))
    assert res.returncode == 0
    assert len(res.stdout) <= MAX_OUTPUT_BYTES + 200
    assert "bytes of output dropped" in res.stdout and res.stdout.rstrip().endswith("END")


def test_stdin_is_fed(tmp_path):
    res = run_sandboxed(py("import sys; print(sys.stdin.read().upper())"), tmp_path,
                        Limits(wall_s=30), stdin=b"hello")
    assert res.returncode == 0 and res.stdout.strip() == "HELLO"


def test_unstartable_program_is_reported_not_raised(tmp_path):
    res = run_sandboxed([str(tmp_path / "no-such-binary")], tmp_path, Limits(wall_s=5))
    assert res.returncode is None and not res.timed_out and "could not start" in res.stderr


def test_network_is_unreachable(tmp_path):
    ok, why = network_isolation_available()
    if not ok:
        pytest.skip(f"network isolation unavailable here: {why}")
    assert why.startswith("unshare")
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(4)
    port = server.getsockname()[1]
    code = (f"import socket\ns = socket.socket()\ns.settimeout(5)\n"
            f"try:\n    s.connect(('127.0.0.1', {port}))\n    print('CONNECTED')\n"
            f"except OSError as e:\n    print('FAILED', e)\n")
    try:
        isolated = run_sandboxed(py(code), tmp_path / "a", Limits(wall_s=30))
        open_net = run_sandboxed(py(code), tmp_path / "b", Limits(wall_s=30, network=True))
    finally:
        server.close()
    assert isolated.network_isolated and isolated.stdout.startswith("FAILED"), isolated.stdout
    assert not open_net.network_isolated and open_net.stdout.startswith("CONNECTED")


def test_unprivileged_child_cannot_write_outside_workdir():
    uid = unprivileged_uid()
    if uid is None:
        pytest.skip("dropping privileges needs a root caller and setpriv")
    work = Path(tempfile.mkdtemp(prefix="visphy-sbx-test-"))
    outside = Path(tempfile.mkdtemp(prefix="visphy-sbx-outside-"))  # root-owned, 0700
    try:
        # /bin/sh, not Python: the interpreter of this venv may live where nobody cannot reach
        script = (f"echo ok > inside.txt; "
                  f"if echo x > {outside / 'x.txt'} 2>/dev/null; then echo WROTE; "
                  f"else echo DENIED; fi; id -u")
        res = run_sandboxed(["/bin/sh", "-c", script], work, Limits(wall_s=30), run_as=uid)
        assert res.returncode == 0, res.stderr
        assert res.stdout.split() == ["DENIED", str(uid)]
        assert (work / "inside.txt").read_text().strip() == "ok"
        assert not (outside / "x.txt").exists()
    finally:
        shutil.rmtree(work, ignore_errors=True)
        shutil.rmtree(outside, ignore_errors=True)


def test_run_as_refuses_unreachable_workdir(tmp_path):
    uid = unprivileged_uid()
    if uid is None:
        pytest.skip("dropping privileges needs a root caller and setpriv")
    hidden = Path(tempfile.mkdtemp(prefix="visphy-sbx-hidden-"))  # 0700: nobody cannot enter
    try:
        with pytest.raises(ValueError, match="not searchable"):
            run_sandboxed(py("pass"), hidden / "work", Limits(wall_s=5), run_as=uid)
    finally:
        shutil.rmtree(hidden, ignore_errors=True)


def test_run_as_needs_root(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("only meaningful for a non-root caller")
    with pytest.raises(ValueError, match="root"):
        run_sandboxed(py("pass"), tmp_path, Limits(wall_s=5), run_as=65534)
