"""Run an untrusted program as a sandboxed child process (shared by the Python engines).

`run_sandboxed` is the one isolation primitive the Python engines use for
model-written code: bubblewrap (``bwrap``) with fresh network, PID, IPC, UTS and mount
namespaces, uid/gid 65534 without capabilities, a seccomp filter (`syscall_filter`) that closes
every way into a new namespace, a new read-only root holding only the interpreter, an
allow-listed environment, rlimits with a work-dir quota, and a wall-clock kill of the whole PID
namespace. Every process the program can see is treated as readable by the program. Limit hits
are reported in ``ProcessResult.limit_hit``; without isolation the program is refused
(``ProcessResult.refused``) unless the user opted out (``sandbox.allow_unisolated``).
Files the program writes are read back with `read_untrusted` (`visphy_core.infra.files`).

This module holds the probe (`isolation_available`, `isolation_level`) and the runner; the
bubblewrap command line is in `visphy_core.sandbox.bwrap`, the limits in
`visphy_core.sandbox.limits`, the output capture in `visphy_core.sandbox.capture` (their names
are re-exported here). What is and is not isolated, each limit and how it is tested:
docs/security.md, the section on the process sandbox of the Python engines.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Iterable

from visphy_core.infra.files import ForeignFileError, open_untrusted, read_upto
from visphy_core.sandbox import syscall_filter
from visphy_core.sandbox.bwrap import (  # noqa: F401 - re-exported for callers
    NOBODY_UID,
    _bwrap_argv,
    _bwrap_path,
    _prepare_workdir,
    _setpriv_path,
    child_env,
    python_ro_paths,
)
from visphy_core.sandbox.capture import (  # noqa: F401 - re-exported for callers
    MAX_OUTPUT_BYTES,
    _Capture,
    _feed,
)
from visphy_core.sandbox.limits import (  # noqa: F401 - re-exported for callers
    DISK_POLL_S,
    Limits,
    _make_preexec,
    _rlimits,
    describe_limit,
    disk_usage,
    limit_from_text,
)
from visphy_core.sandbox.policy import (
    ALLOW_UNISOLATED_ENV,
    set_allow_unisolated,
    unisolated_allowed,
)

log = logging.getLogger(__name__)

INSTALL_HINT = ("install bubblewrap and libseccomp's Python binding (`apt-get install bubblewrap "
                "python3-seccomp`, scripts/setup.sh) on a kernel that allows namespaces and "
                "seccomp, or opt out explicitly with sandbox.allow_unisolated=true "
                f"/ {ALLOW_UNISOLATED_ENV}=1 (model-written code then runs unisolated)")


@dataclass
class ProcessResult:
    """What a sandboxed run did.

    ``returncode`` is the program's exit status (negative: killed by that signal), or None when
    it was killed at the wall-clock/disk limit or could not be started at all (``stderr`` says
    why; ``refused`` is True when the sandbox refused to run untrusted code unisolated).
    ``isolation`` is the isolation the program ran under (`isolation_level`), ``"none"`` for an
    opted-out unisolated run.
    """

    returncode: int | None
    stdout: str
    stderr: str
    timed_out: bool
    limit_hit: str | None   # "wall", "cpu", "memory", "file_size", "disk", "processes" or None
    wall_s: float
    isolation: str
    workdir: Path
    refused: bool = False


# ------------------------------------------------------------------------------ opt-out
def configure(*, allow_unisolated: bool | None = None) -> None:
    """Process-wide settings (the run loop passes config key ``sandbox.allow_unisolated``).
    None leaves the setting to the environment variable ``VISPHY_ALLOW_UNISOLATED``."""
    set_allow_unisolated(allow_unisolated)


# ------------------------------------------------------------------------------ the probe
#: What the probe's command prints inside the sandbox when everything holds: the uid, the
#: seccomp mode of the process, and that a user namespace could not be created.
_PROBE_SCRIPT = ("id -u; grep '^Seccomp:' /proc/self/status | tr -d ' \\t'; "
                 "if unshare --user /bin/true 2>/dev/null; then echo userns-allowed; "
                 "else echo userns-denied; fi")
_PROBE_WANT = f"{NOBODY_UID}\nSeccomp:2\nuserns-denied"


@lru_cache(maxsize=1)
def _probe() -> tuple[str | None, str]:
    """("root" | "user", isolation level) when bwrap and the seccomp filter work here, else
    (None, reason)."""
    bwrap = _bwrap_path()
    if bwrap is None:
        return None, "bubblewrap (bwrap) is not installed"
    root = os.geteuid() == 0
    if root and _setpriv_path() is None:
        return None, "setpriv (util-linux) is not installed"
    ok, why = syscall_filter.available()
    if not ok:
        return None, f"no seccomp filter: {why}"
    mode = "root" if root else "user"
    work = Path(tempfile.mkdtemp(prefix="visphy-bwrap-probe-"))
    seccomp_fd = None
    try:
        _prepare_workdir(work, mode)
        env = {"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8"}
        seccomp_fd = syscall_filter.memfd()
        cmd = _bwrap_argv(bwrap, mode, work, [], env, Limits(),
                          ["/bin/sh", "-c", _PROBE_SCRIPT], seccomp_fd=seccomp_fd)
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=30, env=env,
                              cwd="/", pass_fds=(seccomp_fd,))
    except (OSError, subprocess.TimeoutExpired, syscall_filter.FilterUnavailable) as exc:
        return None, f"bwrap failed to run: {exc}"
    finally:
        if seccomp_fd is not None:
            os.close(seccomp_fd)
        shutil.rmtree(work, ignore_errors=True)
    if proc.returncode != 0 or proc.stdout.strip() != _PROBE_WANT:
        why = (proc.stderr or proc.stdout).strip().splitlines()
        if proc.returncode == 0:
            return None, (f"the seccomp filter does not hold here (the probe printed "
                          f"{proc.stdout.strip()!r}, expected {_PROBE_WANT!r})")
        return None, ("the kernel refuses the namespaces or the seccomp filter bwrap needs "
                      f"(bwrap: {why[-1] if why else f'exit {proc.returncode}'})")
    spaces = "netns,pidns,ipcns,utsns,mountns" if root else "userns,netns,pidns,ipcns,utsns,mountns"
    return mode, f"bwrap:uid{NOBODY_UID},{spaces},nouserns,seccomp"


def isolation_available() -> tuple[bool, str]:
    """(True, isolation level) when programs can run sandboxed here, else (False, reason).
    Probed once per process (one trivial bwrap run)."""
    mode, text = _probe()
    return mode is not None, text


def isolation_level() -> str:
    """What `run_sandboxed` gives a program here, for the run manifest: the bwrap isolation
    (``"bwrap:uid65534,netns,pidns,ipcns,utsns,mountns,nouserns,seccomp"`` as root; a non-root
    caller's adds ``userns``, the sandbox's own user namespace), ``"none"`` when it is unavailable
    and the user opted out, or ``"refused: <reason>"`` when untrusted code will not run."""
    mode, text = _probe()
    if mode is not None:
        return text
    return "none" if unisolated_allowed() else f"refused: {text}"


# ------------------------------------------------------------------------------ reading results
def read_untrusted(path: str | os.PathLike, max_bytes: int) -> bytes | None:
    """A regular file a sandboxed program could have tampered with, read by
    `visphy_core.infra.files` (no symlinks: a link to a file only the host may read must not
    leak into the run; no devices or FIFOs; at most ``max_bytes``, cut off at the size it had
    when opened); None otherwise."""
    try:
        fd, size = open_untrusted(path, max_bytes)
    except (OSError, ForeignFileError):
        return None
    try:
        return read_upto(fd, size)
    finally:
        os.close(fd)


def _refused(workdir: Path, why: str, refused: bool = True) -> ProcessResult:
    return ProcessResult(returncode=None, stdout="", stderr=why, timed_out=False, limit_hit=None,
                         wall_s=0.0, isolation="none", workdir=workdir, refused=refused)


# ------------------------------------------------------------------------------ the primitive
def run_sandboxed(argv: list[str], workdir: Path, limits: Limits,
                  env_extra: dict[str, str] | None = None, stdin: bytes | None = None, *,
                  ro_paths: Iterable[str | os.PathLike] | None = None,
                  allow_secret_env: Iterable[str] = ()) -> ProcessResult:
    """Run ``argv`` in the sandbox described in the module docstring, and wait for it.

    ``workdir`` becomes the program's private cwd, HOME and (``tmp/``) TMPDIR, the only writable
    place; as root it is handed to uid 65534. ``ro_paths`` are the directories the program needs
    read-only besides ``/usr`` (default: `python_ro_paths` of ``argv[0]`` when that is a Python
    interpreter). ``env_extra`` adds variables (secret-looking names are dropped unless listed in
    ``allow_secret_env``). ``stdin`` is fed to the program (else it reads /dev/null). Never
    raises for anything the program does; a sandbox that cannot start is a result with
    ``returncode=None`` and the reason in ``stderr`` (``refused=True`` when isolation is
    unavailable and the user did not opt out).
    """
    workdir = Path(workdir).resolve()
    cmd = [str(a) for a in argv]
    if not cmd:
        raise ValueError("argv is empty")
    mode, level = _probe()
    if mode is None and not unisolated_allowed():
        return _refused(workdir, f"sandbox unavailable, refusing to run untrusted code: {level}; "
                                 f"{INSTALL_HINT}")
    _prepare_workdir(workdir, mode)
    if ro_paths is None:
        ro_paths = python_ro_paths(cmd[0]) if "python" in os.path.basename(cmd[0]) else []
    ro_list = [Path(p) for p in ro_paths]
    if mode is not None:
        bins = [str(p / "bin") for p in ro_list if (p / "bin").is_dir()]
        path = ":".join(dict.fromkeys(bins + ["/usr/local/bin", "/usr/bin", "/bin"]))
    else:
        path = None
    env = child_env(workdir, env_extra, allow_secret_env, path=path)

    planned = _command(cmd, workdir, mode, level, ro_list, env, limits)
    if isinstance(planned, ProcessResult):
        return planned
    full, isolation, uid, seccomp_fd = planned

    preexec = _make_preexec(_rlimits(limits, uid))
    start = time.monotonic()
    started = _start(full, workdir, env, stdin, preexec, seccomp_fd, isolation)
    if isinstance(started, ProcessResult):
        return started
    proc, out, err = started

    hit: list[str] = []
    hit_lock = threading.Lock()
    done = threading.Event()

    def kill_all(reason: str) -> None:
        with hit_lock:
            if not hit:
                hit.append(reason)
        _kill(proc.pid, group=True)
        _kill(proc.pid, group=False)

    def watch() -> None:
        deadline = start + max(0.0, float(limits.wall_s))
        quota = (int(limits.disk_mb) << 20, int(limits.max_files))
        while not done.is_set():
            now = time.monotonic()
            if now >= deadline:
                kill_all("wall")
                return
            used, entries = disk_usage(workdir, stop_at=quota)
            if used > quota[0] or entries > quota[1]:
                kill_all("disk")
                return
            done.wait(min(DISK_POLL_S, max(0.0, deadline - time.monotonic())))

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        try:
            _pid, status, usage = os.wait4(proc.pid, 0)
        except ChildProcessError:  # reaped elsewhere (should not happen)
            status, usage = 0, None
    except BaseException:  # e.g. KeyboardInterrupt in the host: never leave the program running
        kill_all("interrupted")
        proc.wait()
        out.text(1.0)
        err.text(1.0)
        raise
    finally:
        done.set()
    wall = time.monotonic() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if mode is None:
        _kill(proc.pid, group=True)  # stray background children of an unisolated program
    watcher.join(2.0)
    stdout, stderr = out.text(2.0), err.text(2.0)

    returncode, limit_hit = _outcome(proc.returncode, mode, hit, usage, limits, stderr)
    return ProcessResult(returncode=returncode, stdout=stdout, stderr=stderr,
                         timed_out=limit_hit == "wall", limit_hit=limit_hit, wall_s=wall,
                         isolation=isolation, workdir=workdir)


def _command(cmd: list[str], workdir: Path, mode: str | None, level: str, ro_list: list[Path],
             env: dict[str, str], limits: Limits
             ) -> ProcessResult | tuple[list[str], str, int, int | None]:
    """The command line that runs ``cmd`` isolated in ``mode`` (or as is, when the user opted
    out): ``(argv, isolation, uid, seccomp filter fd)``, or the result of refusing to start."""
    # Resolve the program here: behind bwrap a missing binary would only show up as exit 1.
    exe = cmd[0] if os.sep in cmd[0] else shutil.which(cmd[0], path=env["PATH"])
    if exe is None or not os.path.isfile(os.path.join(workdir, exe)) or not os.access(
            os.path.join(workdir, exe), os.X_OK):
        return _refused(workdir, f"could not start {cmd[0]}: not found or not executable",
                        refused=False)
    if mode is None:
        log.warning("sandbox: running %s UNISOLATED (%s; opted out explicitly)", cmd[:1], level)
        return cmd, "none", os.getuid(), None
    try:
        seccomp_fd = syscall_filter.memfd()
    except (OSError, syscall_filter.FilterUnavailable) as exc:
        return _refused(workdir, f"sandbox unavailable, refusing to run untrusted code: "
                                 f"no seccomp filter: {exc}; {INSTALL_HINT}")
    full = [*_bwrap_argv(_bwrap_path() or "bwrap", mode, workdir, ro_list, env, limits,
                         cmd, seccomp_fd=seccomp_fd)]
    return full, level, NOBODY_UID if mode == "root" else os.getuid(), seccomp_fd


def _start(full: list[str], workdir: Path, env: dict[str, str], stdin: bytes | None, preexec,
           seccomp_fd: int | None, isolation: str
           ) -> ProcessResult | tuple[subprocess.Popen, _Capture, _Capture]:
    """Start ``full`` in its own session with piped output (and ``stdin`` fed by a thread); the
    parent's copies of the child's pipe ends and of the filter fd are closed either way."""
    out_r, out_w = os.pipe()
    err_r, err_w = os.pipe()
    in_r, in_w = os.pipe() if stdin is not None else (None, None)
    try:
        proc = subprocess.Popen(
            full, cwd=workdir, env=env, stdin=in_r if in_r is not None else subprocess.DEVNULL,
            stdout=out_w, stderr=err_w, start_new_session=True, preexec_fn=preexec,
            close_fds=True, pass_fds=(seccomp_fd,) if seccomp_fd is not None else ())
    except OSError as exc:
        for fd in (out_r, out_w, err_r, err_w, in_r, in_w):
            if fd is not None:
                os.close(fd)
        res = _refused(workdir, f"could not start {full[0]}: {exc}", refused=False)
        res.isolation = isolation
        return res
    finally:
        for fd in (out_w, err_w, in_r, seccomp_fd):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
    out, err = _Capture(out_r), _Capture(err_r)
    if in_w is not None:
        threading.Thread(target=_feed, args=(in_w, stdin), daemon=True).start()
    return proc, out, err


def _outcome(status: int, mode: str | None, hit: list[str], usage, limits: Limits,
             stderr: str) -> tuple[int | None, str | None]:
    """``(returncode, limit_hit)`` of a finished program: a signal death as a negative code, and
    which limit ended it (None for the return code when the watcher killed it)."""
    returncode: int | None = status
    if mode is not None and returncode is not None and 128 < returncode < 128 + 65:
        returncode = -(returncode - 128)  # bwrap reports a signal death as 128 + signal
    limit_hit: str | None = hit[0] if hit and hit[0] in ("wall", "disk") else None
    cpu_used = (usage.ru_utime + usage.ru_stime) if usage is not None else 0.0
    if limit_hit is not None:
        returncode = None
    elif returncode == -signal.SIGXCPU or (returncode == -signal.SIGKILL
                                            and cpu_used >= math.ceil(limits.cpu_s) - 0.05):
        limit_hit = "cpu"
    elif returncode == -signal.SIGXFSZ:
        limit_hit = "file_size"
    elif returncode != 0:
        limit_hit = limit_from_text(stderr[-8000:])
    return returncode, limit_hit


def _kill(pid: int, group: bool) -> None:
    try:
        if group:
            os.killpg(pid, signal.SIGKILL)
        else:
            os.kill(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
