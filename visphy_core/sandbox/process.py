"""Run an untrusted program as a sandboxed child process (shared by the Python engines).

`run_sandboxed` is the one isolation primitive the Python engines (Manim, Blender) use for
model-written code. What it guarantees, and what it does not:

* **Environment.** The child sees a scrubbed environment: ``PATH``, ``LANG``/``LC_ALL``
  (``C.UTF-8``), ``TZ=UTC``, ``HOME=<workdir>``, ``TMPDIR=<workdir>/tmp``, ``PYTHONHASHSEED=0``,
  plus ``env_extra``. A variable whose name contains KEY, TOKEN, SECRET, PASSWORD, PASSWD or
  CREDENTIAL (case-insensitive) never passes, not even through ``env_extra``, unless the caller
  names it explicitly in ``allow_secret_env`` (a deliberate, greppable opt-in).
* **Working directory.** The child runs with ``cwd = workdir`` (created if missing, mode 0700).
* **Resource limits** (``Limits``), set in the child before ``exec`` (``preexec_fn``):
  ``RLIMIT_CPU`` (SIGXCPU at ``cpu_s``, SIGKILL one second later), ``RLIMIT_AS`` (address
  space, ``memory_mb``), ``RLIMIT_FSIZE`` (largest file the child may write), ``RLIMIT_NPROC``
  (best effort: the kernel counts threads per *user*, so the limit is set to the user's current
  count plus ``processes``; it is not enforced for root) and ``RLIMIT_CORE = 0``. Limits never
  exceed the parent's own hard limits.
* **Wall clock.** The child leads a new session / process group; at ``wall_s`` the whole group
  gets SIGKILL, and so does whatever is left of the group after a normal exit (background
  children). A child that deliberately leaves its process group (``setsid``) escapes this kill;
  running it unprivileged (``run_as``) at least caps how many processes it may create.
* **Network.** With ``Limits.network = False`` the child runs inside a fresh network namespace
  (``unshare -n``; ``unshare -rn`` through a user namespace when not root): no interface but a
  down loopback, so every connect fails with "Network is unreachable". When the kernel refuses
  namespaces the child runs *with* network access and ``ProcessResult.network_isolated`` is
  False: the caller must record that (``network_isolation_available`` says why up front).
* **Output.** stdout and stderr are captured with a size cap (`MAX_OUTPUT_BYTES` per stream:
  the head and the tail are kept, the middle is replaced by a one-line marker).
* **Filesystem.** Full filesystem isolation (a private mount namespace / read-only root) is out
  of scope for now; a later issue hardens it. What exists today: the child starts in its private
  work dir, and when the caller runs as root it may pass ``run_as`` (`unprivileged_uid()`): the
  work dir is handed to that user and the child drops to it (``setpriv --reuid/--regid
  --clear-groups --no-new-privs``) after entering the network namespace, so it can write only
  to its work dir and to world-writable places (``/tmp``, ``/dev/shm``) and cannot regain root.
  It still *reads* whatever is world-readable. Without ``run_as`` the child has the caller's
  own file permissions.

Limit hits are reported in ``ProcessResult.limit_hit``: ``"wall"`` (killed at ``wall_s``),
``"cpu"`` (SIGXCPU, or SIGKILL after using the CPU budget), ``"memory"`` (the child died of an
allocation failure: Python ``MemoryError``, ``std::bad_alloc``, "Cannot allocate memory" on
stderr) or ``"file_size"`` (SIGXFSZ, or ``EFBIG``/"File too large" on stderr; Python ignores
SIGXFSZ, so a Python child sees ``OSError: [Errno 27] File too large``).
"""

from __future__ import annotations

import collections
import logging
import math
import os
import resource
import shutil
import signal
import stat
import subprocess
import threading
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Iterable

log = logging.getLogger(__name__)

#: Bytes of stdout (and, separately, of stderr) kept per run: the first `_HEAD_BYTES` and the last
#: ``MAX_OUTPUT_BYTES - _HEAD_BYTES``.
MAX_OUTPUT_BYTES = 1 << 20
_HEAD_BYTES = 64 << 10
#: Substrings (upper case) of environment variable names that never reach the child.
SECRET_MARKERS = ("KEY", "TOKEN", "SECRET", "PASSWORD", "PASSWD", "CREDENTIAL")
#: The unprivileged user (and group) a root caller can drop the child to: Debian's nobody/nogroup.
NOBODY_UID = 65534

_MEMORY_PATTERNS = ("MemoryError", "bad_alloc", "Cannot allocate memory", "out of memory",
                    "Out of memory")
_FSIZE_PATTERNS = ("File too large", "[Errno 27]")


@dataclass
class Limits:
    """Resource limits of one sandboxed run (seconds, MiB, count)."""

    wall_s: float = 120.0
    cpu_s: float = 120.0
    memory_mb: int = 4096       # address space (RLIMIT_AS), not resident memory
    file_size_mb: int = 1024    # largest single file the child may write
    processes: int = 256        # best effort, see the module docstring
    network: bool = False       # True: no network namespace (the child can reach the network)


@dataclass
class ProcessResult:
    """What a sandboxed run did.

    ``returncode`` is the child's exit status (negative: killed by that signal), or None when it
    was killed at the wall-clock limit or could not be started at all (``stderr`` says why).
    ``network_isolated`` is False when the child ran with network access (asked for, or
    namespaces unavailable): callers must record it.
    """

    returncode: int | None
    stdout: str
    stderr: str
    timed_out: bool
    limit_hit: str | None   # "wall", "cpu", "memory", "file_size" or None
    wall_s: float
    network_isolated: bool
    workdir: Path


# ------------------------------------------------------------------------------ capabilities
@lru_cache(maxsize=1)
def _netns_prefix() -> tuple[tuple[str, ...] | None, str]:
    unshare = shutil.which("unshare")
    if unshare is None:
        return None, "unshare (util-linux) is not installed"
    flags = ("-n",) if os.geteuid() == 0 else ("-rn",)
    cmd = (unshare, *flags, "--")
    try:
        proc = subprocess.run([*cmd, "true"], capture_output=True, text=True, timeout=10,
                              env={"PATH": os.environ.get("PATH", os.defpath)})
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"`unshare {' '.join(flags)} true` failed to run: {exc}"
    if proc.returncode != 0:
        why = (proc.stderr or proc.stdout).strip().splitlines()
        return None, (f"the kernel refuses network namespaces (`unshare {' '.join(flags)}`: "
                      f"{why[-1] if why else f'exit {proc.returncode}'})")
    return cmd, f"unshare {' '.join(flags)}"


def network_isolation_available() -> tuple[bool, str]:
    """(True, "unshare -n") when children can run without any network, else (False, reason).

    Probed once per process (runs ``unshare -n true``; ``unshare -rn`` when not root).
    """
    prefix, how = _netns_prefix()
    return prefix is not None, how


def unprivileged_uid() -> int | None:
    """The uid a root caller may pass as ``run_as`` (nobody), or None when dropping is impossible
    (not root, or ``setpriv`` missing)."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        return None
    return NOBODY_UID


# ------------------------------------------------------------------------------ environment
def _is_secret(name: str) -> bool:
    upper = name.upper()
    return any(marker in upper for marker in SECRET_MARKERS)


def child_env(workdir: Path, env_extra: dict[str, str] | None = None,
              allow_secret_env: Iterable[str] = ()) -> dict[str, str]:
    """The scrubbed environment of a sandboxed child (see the module docstring)."""
    env = {
        "PATH": os.environ.get("PATH") or os.defpath,
        "LANG": "C.UTF-8",
        "LC_ALL": "C.UTF-8",
        "TZ": "UTC",
        "HOME": str(workdir),
        "TMPDIR": str(workdir / "tmp"),
        "PYTHONHASHSEED": "0",
    }
    allowed = set(allow_secret_env)
    dropped = []
    for name, value in (env_extra or {}).items():
        if _is_secret(name) and name not in allowed:
            dropped.append(name)
            continue
        env[str(name)] = str(value)
    if dropped:
        log.warning("sandbox: not passing secret-looking variables %s (name them in "
                    "allow_secret_env to pass them)", ", ".join(sorted(dropped)))
    return env


# ------------------------------------------------------------------------------ limits
def _threads_of_uid(uid: int) -> int:
    """Threads the kernel counts against RLIMIT_NPROC for ``uid`` (best effort, via /proc)."""
    count = 0
    try:
        entries = os.listdir("/proc")
    except OSError:
        return 0
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/status", "rb") as fh:
                text = fh.read().decode("ascii", "replace")
        except OSError:
            continue
        uid_ok, threads = False, 1
        for line in text.splitlines():
            if line.startswith("Uid:"):
                uid_ok = line.split()[1] == str(uid)
            elif line.startswith("Threads:"):
                threads = int(line.split()[1])
        if uid_ok:
            count += threads
    return count


def _capped(res: int, want: int) -> tuple[int, int]:
    _soft, hard = resource.getrlimit(res)
    if hard != resource.RLIM_INFINITY:
        want = min(want, hard)
    return want, want


def _rlimits(limits: Limits, uid: int) -> list[tuple[int, tuple[int, int]]]:
    cpu = max(1, math.ceil(limits.cpu_s))
    _s, cpu_hard = resource.getrlimit(resource.RLIMIT_CPU)
    cpu_pair = (cpu, cpu + 1) if cpu_hard == resource.RLIM_INFINITY else (
        min(cpu, cpu_hard), min(cpu + 1, cpu_hard))
    out = [
        (resource.RLIMIT_CPU, cpu_pair),
        (resource.RLIMIT_AS, _capped(resource.RLIMIT_AS, int(limits.memory_mb) << 20)),
        (resource.RLIMIT_FSIZE, _capped(resource.RLIMIT_FSIZE, int(limits.file_size_mb) << 20)),
        (resource.RLIMIT_CORE, (0, 0)),
    ]
    nproc = _threads_of_uid(uid) + max(1, int(limits.processes))
    out.append((resource.RLIMIT_NPROC, _capped(resource.RLIMIT_NPROC, nproc)))
    return out


def _make_preexec(rlimits: list[tuple[int, tuple[int, int]]]):
    # Runs between fork and exec: keep it to system calls on precomputed values (no imports, no
    # allocation-heavy work), so it stays safe even when the parent has other threads.
    setrlimit = resource.setrlimit

    def preexec() -> None:
        for res, pair in rlimits:
            try:
                setrlimit(res, pair)
            except (ValueError, OSError):
                pass

    return preexec


# ------------------------------------------------------------------------------ output capture
class _Capture:
    """Drain one pipe to EOF, keeping the head and the tail (bounded memory)."""

    def __init__(self, stream, cap: int = MAX_OUTPUT_BYTES):
        self.stream = stream
        self.head = bytearray()
        self.tail: collections.deque[bytes] = collections.deque()
        self.tail_len = 0
        self.dropped = 0
        self.head_cap = min(_HEAD_BYTES, cap)
        self.tail_cap = cap - self.head_cap
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        read = self.stream.read1 if hasattr(self.stream, "read1") else self.stream.read
        try:
            while True:
                chunk = read(65536)
                if not chunk:
                    break
                room = self.head_cap - len(self.head)
                if room > 0:
                    self.head += chunk[:room]
                    chunk = chunk[room:]
                if chunk:
                    self.tail.append(chunk)
                    self.tail_len += len(chunk)
                    while self.tail_len - len(self.tail[0]) >= self.tail_cap:
                        self.dropped += len(self.tail[0])
                        self.tail_len -= len(self.tail[0])
                        self.tail.popleft()
        except (OSError, ValueError):
            pass

    def text(self, join_timeout: float) -> str:
        self.thread.join(join_timeout)
        tail = b"".join(self.tail)
        excess = max(0, len(tail) - self.tail_cap)
        dropped = self.dropped + excess
        middle = f"\n[... {dropped} bytes of output dropped ...]\n".encode() if dropped else b""
        return (bytes(self.head) + middle + tail[excess:]).decode("utf-8", "replace")


def _feed(stream, data: bytes) -> None:
    try:
        stream.write(data)
    except (BrokenPipeError, OSError, ValueError):
        pass
    finally:
        try:
            stream.close()
        except OSError:
            pass


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


# ------------------------------------------------------------------------------ work dir
def _prepare_workdir(workdir: Path, run_as: int | None) -> None:
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / "tmp").mkdir(exist_ok=True)
    os.chmod(workdir, 0o700)
    if run_as is None:
        return
    for parent in workdir.parents:
        mode = parent.stat().st_mode
        if not mode & stat.S_IXOTH:
            raise ValueError(f"run_as={run_as}: {parent} is not searchable by other users, so "
                             f"the child could not reach its work dir {workdir}")
    for root, dirs, files in os.walk(workdir):
        os.chown(root, run_as, run_as)
        for name in dirs + files:
            os.chown(os.path.join(root, name), run_as, run_as, follow_symlinks=False)


# ------------------------------------------------------------------------------ the primitive
def run_sandboxed(argv: list[str], workdir: Path, limits: Limits,
                  env_extra: dict[str, str] | None = None, stdin: bytes | None = None, *,
                  allow_secret_env: Iterable[str] = (), run_as: int | None = None
                  ) -> ProcessResult:
    """Run ``argv`` in the sandbox described in the module docstring, and wait for it.

    ``workdir`` becomes the child's private cwd, HOME and (``tmp/``) TMPDIR. ``env_extra`` adds
    variables (secret-looking names are dropped unless listed in ``allow_secret_env``).
    ``stdin`` is fed to the child (else it reads /dev/null). ``run_as`` (root callers only; see
    `unprivileged_uid`) chowns the work dir to that uid/gid and runs the child as that user with
    no way back to root; the caller must make sure that user can reach the program and
    everything it loads (an interpreter under a 0700 ``/root`` is *not* reachable, and a dynamic
    linker may then silently pick another libpython): probe once with the real interpreter, as
    the Manim engine's ``sandbox_user`` does. Never raises for anything the child does; raises
    ValueError for a bad request (``run_as`` when not root, or a work dir other users cannot
    reach).
    """
    workdir = Path(workdir).resolve()
    if run_as is not None and os.geteuid() != 0:
        raise ValueError("run_as needs a root caller")
    if run_as is not None and shutil.which("setpriv") is None:
        raise ValueError("run_as needs setpriv (util-linux)")
    _prepare_workdir(workdir, run_as)
    env = child_env(workdir, env_extra, allow_secret_env)

    cmd = [str(a) for a in argv]
    if not cmd:
        raise ValueError("argv is empty")
    # Resolve the program here: behind unshare/setpriv a missing binary would only show up as
    # their exit status 127.
    exe = cmd[0] if os.sep in cmd[0] else shutil.which(cmd[0], path=env["PATH"])
    if exe is None or not os.path.isfile(os.path.join(workdir, exe)) or not os.access(
            os.path.join(workdir, exe), os.X_OK):
        return ProcessResult(returncode=None, stdout="",
                             stderr=f"could not start {cmd[0]}: not found or not executable",
                             timed_out=False, limit_hit=None, wall_s=0.0,
                             network_isolated=False, workdir=workdir)
    network_isolated = False
    if not limits.network:
        prefix, how = _netns_prefix()
        if prefix is not None:
            network_isolated = True
        else:
            log.warning("sandbox: running %s WITH network access: %s", cmd[:1], how)
    if run_as is not None:
        cmd = [shutil.which("setpriv") or "setpriv", f"--reuid={run_as}", f"--regid={run_as}",
               "--clear-groups", "--no-new-privs", "--", *cmd]
    if network_isolated:
        cmd = [*prefix, *cmd]  # type: ignore[misc]

    uid = run_as if run_as is not None else os.getuid()
    preexec = _make_preexec(_rlimits(limits, uid))
    start = time.monotonic()
    try:
        proc = subprocess.Popen(
            cmd, cwd=workdir, env=env, stdin=subprocess.PIPE if stdin is not None else
            subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            start_new_session=True, preexec_fn=preexec, close_fds=True)
    except OSError as exc:
        return ProcessResult(returncode=None, stdout="", stderr=f"could not start {cmd[0]}: {exc}",
                             timed_out=False, limit_hit=None, wall_s=time.monotonic() - start,
                             network_isolated=network_isolated, workdir=workdir)
    out, err = _Capture(proc.stdout), _Capture(proc.stderr)
    if stdin is not None:
        threading.Thread(target=_feed, args=(proc.stdin, stdin), daemon=True).start()

    timed_out = threading.Event()

    def on_wall() -> None:
        timed_out.set()
        _kill_group(proc.pid)

    timer = threading.Timer(max(0.0, float(limits.wall_s)), on_wall)
    timer.daemon = True
    timer.start()
    try:
        try:
            _pid, status, usage = os.wait4(proc.pid, 0)
        except ChildProcessError:  # reaped elsewhere (should not happen)
            status, usage = 0, None
    except BaseException:  # e.g. KeyboardInterrupt in the host: never leave the child running
        _kill_group(proc.pid)
        proc.kill()
        proc.wait()
        raise
    finally:
        timer.cancel()
    wall = time.monotonic() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    _kill_group(proc.pid)  # stray background children of a finished program
    stdout, stderr = out.text(5.0), err.text(5.0)
    for stream in (proc.stdout, proc.stderr):
        try:
            stream.close()
        except OSError:
            pass

    returncode: int | None = proc.returncode
    limit_hit: str | None = None
    cpu_used = (usage.ru_utime + usage.ru_stime) if usage is not None else 0.0
    if timed_out.is_set():
        limit_hit, returncode = "wall", None
    elif returncode == -signal.SIGXCPU or (returncode == -signal.SIGKILL
                                            and cpu_used >= math.ceil(limits.cpu_s) - 0.05):
        limit_hit = "cpu"
    elif returncode == -signal.SIGXFSZ:
        limit_hit = "file_size"
    elif returncode != 0:
        tail = stderr[-8000:]
        if any(p in tail for p in _MEMORY_PATTERNS):
            limit_hit = "memory"
        elif any(p in tail for p in _FSIZE_PATTERNS):
            limit_hit = "file_size"
    return ProcessResult(returncode=returncode, stdout=stdout, stderr=stderr,
                         timed_out=limit_hit == "wall", limit_hit=limit_hit, wall_s=wall,
                         network_isolated=network_isolated, workdir=workdir)
