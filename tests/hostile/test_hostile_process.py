"""Hostile programs against the process sandbox (bubblewrap) of the Manim and Blender engines.

Each case is a model-written program that attacks the host: network egress to the canary's
loopback TCP/UDP server, namespace re-entry through ``/proc/<pid>/ns/net``, ancestor ``/proc``
reads, secrets in the environment, in files and in exception messages, writes outside the work
dir, fork bombs and process floods, detached ``setsid`` grandchildren, infinite loops, unbounded
memory, huge output and huge files. For every case: the canary records zero hits, no canary value
shows up in the result (error, logs) or in anything the render left behind, the render ends
within its limit plus a small margin, no process of it survives, the failure class is the
expected one, and the next (good) program renders with the same engine.
"""

from __future__ import annotations

import os
import secrets
import shutil
import sys
import tempfile
import textwrap
import time

import pytest

from visphy_core.engine import FailureClass, Program, RenderContract
from visphy_core.sandbox.process import isolation_available

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
