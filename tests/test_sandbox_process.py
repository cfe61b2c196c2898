"""The process sandbox shared by the Python engines (bubblewrap): user, namespaces, filesystem
view, environment, limits, wall-clock kill of the whole tree, output capture, and the refusal to
run untrusted code without isolation."""

from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from hostile.conftest import wait_no_survivors  # tests/ is on sys.path (pytest rootdir)

from visphy_core.sandbox import process as sp
from visphy_core.sandbox.process import (
    MAX_OUTPUT_BYTES,
    NOBODY_UID,
    Limits,
    child_env,
    isolation_available,
    isolation_level,
    python_ro_paths,
    run_sandboxed,
)

PY = sys.executable
ISOLATED, WHY = isolation_available()
needs_bwrap = pytest.mark.skipif(not ISOLATED, reason=f"no bubblewrap sandbox here: {WHY}")


def py(code: str) -> list[str]:
    return [PY, "-s", "-B", "-c", code]


@pytest.fixture
def work():
    """A work dir the way the engines make one (mkdtemp under /tmp)."""
    path = Path(tempfile.mkdtemp(prefix="visphy-sbx-test-"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


# ------------------------------------------------------------------------------ environment
def test_environment_is_scrubbed(work, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", "sk-parent-secret")
    monkeypatch.setenv("VISPHY_SOMETHING", "parent-only")
    res = run_sandboxed(py("import json, os; print(json.dumps(dict(os.environ)))"), work,
                        Limits(wall_s=30),
                        env_extra={"FOO": "bar", "MY_SECRET_TOKEN": "t", "DB_PASSWORD": "p"})
    assert res.returncode == 0, res.stderr
    env = json.loads(res.stdout)
    assert "sk-parent-secret" not in res.stdout
    assert "OPENAI_API_KEY" not in env and "VISPHY_SOMETHING" not in env
    assert "MY_SECRET_TOKEN" not in env and "DB_PASSWORD" not in env  # even via env_extra
    assert env["FOO"] == "bar"
    assert env["TZ"] == "UTC" and env["PYTHONHASHSEED"] == "0"
    # PWD: set by bwrap's --chdir; LC_CTYPE: Python's own C-locale coercion may add it
    assert set(env) <= {"PATH", "LANG", "LC_ALL", "TZ", "HOME", "TMPDIR", "PYTHONHASHSEED", "FOO",
                        "LC_CTYPE", "PWD"}


def test_secret_passes_only_when_named_explicitly(tmp_path):
    env = child_env(tmp_path, {"HF_TOKEN": "x", "API_KEY": "y", "X_AUTH": "z"},
                    allow_secret_env=["HF_TOKEN"])
    assert env["HF_TOKEN"] == "x" and "API_KEY" not in env and "X_AUTH" not in env


def test_workdir_is_cwd_and_home(work):
    code = ("import json, os; print(json.dumps([os.getcwd(), os.environ['HOME'], "
            "os.environ['TMPDIR'], os.path.isdir(os.environ['TMPDIR'])]))")
    res = run_sandboxed(py(code), work / "w", Limits(wall_s=30))
    assert res.returncode == 0, res.stderr
    cwd, home, tmpdir, tmp_exists = json.loads(res.stdout)
    assert Path(cwd) == (work / "w").resolve() == Path(home) == res.workdir
    assert Path(tmpdir) == (work / "w").resolve() / "tmp" and tmp_exists


def test_python_ro_paths_are_the_venv_and_its_base():
    paths = python_ro_paths(sys.executable)
    assert Path(os.path.realpath(sys.prefix)) in paths
    assert Path(os.path.realpath(sys.base_prefix)) in paths


# ------------------------------------------------------------------------------ isolation
@needs_bwrap
def test_isolation_level_is_recorded(work):
    res = run_sandboxed(["/bin/true"], work, Limits(wall_s=10))
    assert res.returncode == 0 and res.isolation == isolation_level() == WHY
    assert res.isolation.startswith(f"bwrap:uid{NOBODY_UID},")
    for ns in ("netns", "pidns", "ipcns", "utsns", "mountns"):
        assert ns in res.isolation


HOSTILE_PROBE = r"""
import ctypes, json, os
out = {"uid": os.getuid(), "euid": os.geteuid(), "gid": os.getgid()}
pids = [int(p) for p in os.listdir("/proc") if p.isdigit()]
out["pids"] = pids
environ = {}
for pid in pids:
    for what in ("environ", "cmdline"):
        try:
            environ[f"{pid}/{what}"] = open(f"/proc/{pid}/{what}", "rb").read().decode("latin-1")
        except OSError as exc:
            environ[f"{pid}/{what}"] = "ERR " + type(exc).__name__
out["proc"] = environ
libc = ctypes.CDLL(None, use_errno=True)
setns = {}
for pid in pids:
    try:
        fd = os.open(f"/proc/{pid}/ns/net", os.O_RDONLY)
    except OSError as exc:
        setns[pid] = "open " + type(exc).__name__
        continue
    rc = libc.setns(fd, 0)
    setns[pid] = "ok" if rc == 0 else f"errno {ctypes.get_errno()}"
out["setns"] = setns
def read(path):
    try:
        return open(path).read()[:200]
    except OSError as exc:
        return "ERR " + type(exc).__name__
out["host_file"] = read("__HOST_FILE__")
out["passwd"] = read("/etc/passwd")
out["project"] = read("__PROJECT__")
out["root"] = sorted(os.listdir("/"))
writes = {}
for target in ("/x", "/usr/x", "__VENV__/x", "/etc/x", "/tmp/x", "/dev/shm/x", "__OUTSIDE__/x"):
    try:
        with open(target, "w") as fh:
            fh.write("x")
        writes[target] = "wrote"
    except OSError as exc:
        writes[target] = "ERR " + type(exc).__name__
out["writes"] = writes
import socket
try:
    s = socket.create_connection(("127.0.0.1", __PORT__), timeout=2)
    out["tcp"] = "connected"
except OSError as exc:
    out["tcp"] = "ERR " + str(exc)
u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
try:
    u.sendto(b"leak", ("127.0.0.1", __PORT__))
except OSError as exc:
    pass
print(json.dumps(out))
"""


@needs_bwrap
def test_the_program_sees_nothing_of_the_host(work, tmp_path, monkeypatch):
    secret = "parent-secret-" + secrets.token_hex(8)
    monkeypatch.setenv("VISPHY_TEST_API_KEY", secret)
    host_file = tmp_path / "host.txt"
    host_file.write_text("host-file-" + secret)
    host_file.chmod(0o644)
    outside = Path(tempfile.mkdtemp(prefix="visphy-sbx-outside-"))
    outside.chmod(0o777)  # even a world-writable host dir is out of reach
    tcp = socket.socket()
    tcp.bind(("127.0.0.1", 0))
    tcp.listen(4)
    tcp.settimeout(0.2)
    port = tcp.getsockname()[1]
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", port))
    udp.settimeout(0.2)
    code = (HOSTILE_PROBE.replace("__HOST_FILE__", str(host_file))
            .replace("__VENV__", sys.prefix).replace("__OUTSIDE__", str(outside))
            .replace("__PORT__", str(port))
            .replace("__PROJECT__", str(Path(__file__).resolve().parents[1] / "pyproject.toml")))
    try:
        res = run_sandboxed(py(code), work, Limits(wall_s=30))
        with pytest.raises(OSError):
            tcp.accept()
        with pytest.raises(OSError):
            udp.recvfrom(100)
    finally:
        tcp.close()
        udp.close()
    try:
        assert res.returncode == 0, res.stderr
        assert secret not in res.stdout + res.stderr
        out = json.loads(res.stdout)
        assert out["uid"] == out["euid"] == out["gid"] == NOBODY_UID
        assert len(out["pids"]) <= 4 and all(pid < 10 for pid in out["pids"])  # own pidns
        assert out["setns"] and "ok" not in out["setns"].values(), out["setns"]
        assert out["host_file"].startswith("ERR") and out["passwd"].startswith("ERR")
        assert "home" not in out["root"] and out["project"].startswith("ERR")
        assert out["tcp"].startswith("ERR")
        w = out["writes"]
        for target in ("/x", "/usr/x", f"{sys.prefix}/x", "/etc/x", f"{outside}/x"):
            assert w[target].startswith("ERR"), (target, w[target])
        assert w["/tmp/x"] == "wrote" and (work / "tmp" / "x").exists()  # /tmp = work/tmp
        assert w["/dev/shm/x"] == "wrote" and not Path("/dev/shm/x").exists()  # private tmpfs
        assert not list(outside.iterdir())
    finally:
        shutil.rmtree(outside, ignore_errors=True)


@needs_bwrap
def test_proc_1_environ_holds_no_parent_secret(work, monkeypatch):
    secret = "environ-secret-" + secrets.token_hex(8)
    monkeypatch.setenv("VISPHY_TEST_TOKEN", secret)
    code = ("import os\nfor p in os.listdir('/proc'):\n    if p.isdigit():\n        try:\n"
            "            print(open(f'/proc/{p}/environ', 'rb').read())\n"
            "        except OSError as e:\n            print(p, 'ERR', e)\n")
    res = run_sandboxed(py(code), work, Limits(wall_s=30))
    assert res.returncode == 0, res.stderr
    assert secret not in res.stdout and "VISPHY_TEST_TOKEN" not in res.stdout
    if os.geteuid() == 0:  # bwrap (PID 1, root) is not readable by uid 65534
        assert "1 ERR" in res.stdout


# ------------------------------------------------------------------------------ wall clock
#: How long the children of the wall-clock tests sleep. The tests bound time only against it
#: (the call returned long before a child would have ended by itself, so it did not wait for
#: one), never against a tight constant: how soon a kill lands is for benchmarks/, and a loaded
#: CI machine may take seconds more.
CHILD_SLEEP_S = 300


def test_wall_timeout_kills_loop_and_children(work):
    marker = "visphy-wall-" + secrets.token_hex(6)
    code = ("import subprocess, sys\n"
            f"subprocess.Popen([sys.executable, '-c', 'import time; time.sleep({CHILD_SLEEP_S})', "
            f"'{marker}'])\n"
            "while True: pass\n")
    start = time.monotonic()
    res = run_sandboxed(py(code), work, Limits(wall_s=2, cpu_s=60))
    took = time.monotonic() - start
    assert res.timed_out and res.limit_hit == "wall" and res.returncode is None
    assert res.wall_s >= 1.9  # not before the limit
    assert took < CHILD_SLEEP_S / 2 and res.wall_s < CHILD_SLEEP_S / 2, (took, res.wall_s)
    assert wait_no_survivors(marker) == []  # the whole tree is gone, the sleeping child too


DETACHED = """
import os, sys, time
if os.fork() == 0:
    os.setsid()
    if os.fork() == 0:
        # the grandchild keeps stdout/stderr open and sleeps, marked with {marker!r}
        os.execv(sys.executable, [sys.executable, "-c", "import time; time.sleep({sleep})",
                                  {marker!r}])
    os._exit(0)
print("parent done", flush=True)
{tail}
"""


@pytest.mark.parametrize("tail, wall", [("", 20.0), ("while True: pass", 2.0)])
def test_detached_grandchild_holding_stdout_dies_and_never_blocks(work, tail, wall):
    marker = "visphy-detached-" + secrets.token_hex(6)
    start = time.monotonic()
    res = run_sandboxed(py(DETACHED.format(marker=marker, tail=tail, sleep=CHILD_SLEEP_S)),
                        work, Limits(wall_s=wall, cpu_s=60))
    took = time.monotonic() - start
    assert "parent done" in res.stdout
    if tail:
        assert res.limit_hit == "wall" and res.returncode is None, res
    else:
        # ended with its parent: had it waited for the sleeper holding stdout, the wall limit
        # would have killed it (limit_hit "wall", no return code)
        assert res.returncode == 0 and res.limit_hit is None, (took, res)
    assert took < CHILD_SLEEP_S / 2, took  # the grandchild holding stdout never blocked it
    assert wait_no_survivors(marker) == []


# ------------------------------------------------------------------------------ limits
def test_memory_limit_stops_a_10_gb_allocation(work):
    res = run_sandboxed(py("x = bytearray(10 * 1024 ** 3); print('allocated')"), work,
                        Limits(wall_s=60, memory_mb=1024))
    assert res.returncode not in (0, None)
    assert res.limit_hit == "memory", res.stderr
    assert "allocated" not in res.stdout


def test_file_size_limit(work):
    code = "open('big.bin', 'wb').write(b'x' * (3 << 20)); print('wrote')"
    res = run_sandboxed(py(code), work, Limits(wall_s=30, file_size_mb=1))
    assert res.returncode != 0 and res.limit_hit == "file_size", res.stderr
    assert (work / "big.bin").stat().st_size <= 1 << 20


def test_disk_quota_of_the_work_dir(work):
    # many files, each below the file-size limit, together over the quota (also via /tmp)
    code = ("import os, time\nfor i in range(400):\n"
            "    open(f'/tmp/f{i}' if i % 2 else f'f{i}', 'wb').write(os.urandom(1 << 20))\n"
            "print('wrote all')\ntime.sleep(5)\n")
    res = run_sandboxed(py(code), work, Limits(wall_s=30, disk_mb=20, file_size_mb=4))
    # killed by the quota watcher, not at the 30 s wall limit (that would read "wall")
    assert res.limit_hit == "disk" and res.returncode is None, (res.limit_hit, res.stderr)
    assert "wrote all" not in res.stdout
    used, _entries = sp.disk_usage(work)
    assert used < 120 << 20


def test_too_many_files_is_a_disk_hit(work):
    code = "import time\nfor i in range(100000):\n    open(f'f{i}', 'w').close()\ntime.sleep(5)\n"
    res = run_sandboxed(py(code), work, Limits(wall_s=30, max_files=500))
    assert res.limit_hit == "disk", res.stderr


def test_cpu_limit(work):
    res = run_sandboxed(py("while True: pass"), work, Limits(wall_s=30, cpu_s=1))
    assert res.limit_hit == "cpu" and not res.timed_out and res.returncode not in (0, None)


@needs_bwrap
def test_process_limit(work):
    code = ("import os, time\nn = 0\ntry:\n    for _ in range(1000):\n"
            "        if os.fork() == 0:\n            time.sleep(30)\n            os._exit(0)\n"
            "        n += 1\nexcept OSError as exc:\n    print('forked', n)\n    raise\n")
    res = run_sandboxed(py(code), work, Limits(wall_s=20, processes=20))
    # the refused fork ended the program; had the run waited for the 30 s sleepers, the 20 s
    # wall limit would have killed it and the hit would read "wall"
    assert res.limit_hit == "processes", (res.returncode, res.stderr[-500:])
    assert "forked" in res.stdout, (res.stdout[-200:], res.stderr[-500:])


def test_output_is_capped(work):
    res = run_sandboxed(py("import sys; sys.stdout.write('a' * (8 << 20)); print('END')"),
                        work, Limits(wall_s=30))
    assert res.returncode == 0
    assert len(res.stdout) <= MAX_OUTPUT_BYTES + 200
    assert "bytes of output dropped" in res.stdout and res.stdout.rstrip().endswith("END")


def test_stdin_is_fed(work):
    res = run_sandboxed(py("import sys; print(sys.stdin.read().upper())"), work,
                        Limits(wall_s=30), stdin=b"hello")
    assert res.returncode == 0 and res.stdout.strip() == "HELLO"


def test_unstartable_program_is_reported_not_raised(work):
    res = run_sandboxed([str(work / "no-such-binary")], work, Limits(wall_s=5))
    assert res.returncode is None and not res.timed_out and "could not start" in res.stderr
    assert not res.refused


# ------------------------------------------------------------------------------ no isolation
@pytest.fixture
def no_bwrap(monkeypatch):
    """Pretend bubblewrap is unavailable (as on a kernel that refuses namespaces)."""
    monkeypatch.setattr(sp, "_probe", lambda: (None, "bubblewrap (bwrap) is not installed"))
    monkeypatch.delenv(sp.ALLOW_UNISOLATED_ENV, raising=False)
    sp.configure(allow_unisolated=None)
    yield
    sp.configure(allow_unisolated=None)


def test_refuses_untrusted_code_without_isolation(work, no_bwrap):
    res = run_sandboxed(py("open('ran', 'w').write('1')"), work, Limits(wall_s=10))
    assert res.refused and res.returncode is None
    assert "refusing" in res.stderr and "install bubblewrap" in res.stderr
    assert "allow_unisolated" in res.stderr
    assert not (work / "ran").exists()
    assert isolation_level().startswith("refused: ")


@pytest.mark.parametrize("how", ["env", "configure"])
def test_explicit_opt_out_runs_unisolated(work, no_bwrap, monkeypatch, how):
    if how == "env":
        monkeypatch.setenv(sp.ALLOW_UNISOLATED_ENV, "1")
    else:
        sp.configure(allow_unisolated=True)
    marker = "visphy-unisolated-" + secrets.token_hex(6)
    code = (f"import subprocess, sys\nsubprocess.Popen([sys.executable, '-c', "
            f"'import time; time.sleep(300)', '{marker}'])\nprint('ran')\n")
    res = run_sandboxed(py(code), work, Limits(wall_s=10))
    assert res.returncode == 0 and res.stdout.strip() == "ran" and res.isolation == "none"
    assert isolation_level() == "none"
    assert wait_no_survivors(marker) == []  # the process group is still killed


def test_configure_false_overrides_the_env_var(work, no_bwrap, monkeypatch):
    monkeypatch.setenv(sp.ALLOW_UNISOLATED_ENV, "1")
    sp.configure(allow_unisolated=False)
    assert run_sandboxed(["/bin/true"], work, Limits(wall_s=5)).refused


@needs_bwrap
def test_non_root_caller_uses_a_user_namespace():
    """Run the sandbox from a non-root caller: as root, become uid 65534 with the system Python
    (setpriv); a caller that is not root already is one, and runs it with this Python."""
    repo = Path(__file__).resolve().parents[1]
    base = Path(tempfile.mkdtemp(prefix="visphy-sbx-user-"))
    base.chmod(0o777)
    code = ("import sys; sys.path.insert(0, %r)\nfrom pathlib import Path\n"
            "from visphy_core.sandbox.process import run_sandboxed, Limits\n"
            "r = run_sandboxed(['/bin/sh', '-c', 'id -u; ls /proc | grep -c [0-9]; "
            "cat /etc/passwd || echo nopasswd'], Path(%r), Limits(wall_s=20))\n"
            "print(r.isolation); print(r.stdout)\n") % (str(repo), str(base / "w"))
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None or not os.access("/usr/bin/python3", os.X_OK):
            pytest.skip("becoming a non-root caller needs setpriv and the system python3")
        cmd = ["setpriv", f"--reuid={NOBODY_UID}", f"--regid={NOBODY_UID}", "--clear-groups",
               "/usr/bin/python3", "-c", code]
        env = {"PATH": "/usr/bin:/bin"}
    else:
        cmd, env = [PY, "-c", code], {"PATH": os.environ.get("PATH", "/usr/bin:/bin")}
    try:
        out = subprocess.run(cmd, cwd="/", capture_output=True, text=True, timeout=60, env=env)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    if "No module named" in out.stderr:
        pytest.skip(f"the system python cannot import visphy_core: {out.stderr[-200:]}")
    lines = out.stdout.split()
    assert out.returncode == 0, out.stderr
    assert lines[0].startswith("bwrap:") and "userns" in lines[0], out.stdout
    assert lines[1] == str(NOBODY_UID) and int(lines[2]) <= 4 and lines[3] == "nopasswd"
