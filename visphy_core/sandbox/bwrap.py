"""The bubblewrap command line of a sandboxed program (`visphy_core.sandbox.process`).

Where ``bwrap`` and ``setpriv`` are, the work dir handed to the sandbox's user, the scrubbed
environment (`child_env`), the read-only directories a Python interpreter needs
(`python_ro_paths`) and the ``bwrap`` argv itself (`_bwrap_argv`): namespaces, uid/gid 65534,
the seccomp filter's descriptor, the new root with its read-only binds. What each part isolates
and why: docs/security.md, the process sandbox section.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Sequence

from visphy_core.infra.secrets import is_secret_name
from visphy_core.sandbox.limits import Limits

#: The process sandbox's logger (the name its records always had).
log = logging.getLogger("visphy_core.sandbox.process")

#: The unprivileged user (and group) the program runs as: Debian's nobody/nogroup.
NOBODY_UID = 65534


# ------------------------------------------------------------------------------ the binaries
def _bwrap_path() -> str | None:
    found = shutil.which("bwrap")
    if found is None and os.path.exists("/usr/bin/bwrap"):
        found = "/usr/bin/bwrap"
    return found


def _setpriv_path() -> str | None:
    found = shutil.which("setpriv")
    if found is None and os.path.exists("/usr/bin/setpriv"):
        found = "/usr/bin/setpriv"
    return found


@lru_cache(maxsize=1)
def _bwrap_disables_userns() -> bool:
    """Whether this bwrap has ``--disable-userns`` (bubblewrap 0.8 and later)."""
    bwrap = _bwrap_path()
    if bwrap is None:
        return False
    try:
        proc = subprocess.run([bwrap, "--help"], capture_output=True, text=True, timeout=10,
                              env={"PATH": "/usr/bin:/bin"}, cwd="/")
    except (OSError, subprocess.SubprocessError):
        return False
    return "--disable-userns" in proc.stdout + proc.stderr


# ------------------------------------------------------------------------------ environment
def child_env(workdir: Path, env_extra: dict[str, str] | None = None,
              allow_secret_env: Iterable[str] = (), path: str | None = None) -> dict[str, str]:
    """The scrubbed environment of a sandboxed program (docs/security.md)."""
    env = {
        "PATH": path or os.environ.get("PATH") or os.defpath,
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
        if is_secret_name(str(name)) and name not in allowed:
            dropped.append(name)
            continue
        env[str(name)] = str(value)
    if dropped:
        log.warning("sandbox: not passing secret-looking variables %s (name them in "
                    "allow_secret_env to pass them)", ", ".join(sorted(dropped)))
    return env


def python_ro_paths(python: str | os.PathLike) -> list[Path]:
    """The directories a Python interpreter needs read-only in the sandbox: its venv (when it
    is one) and the installation the venv is based on. ``sys.executable`` gives this process's
    own ``sys.prefix`` and ``sys.base_prefix``."""
    exe = Path(python)
    if not exe.is_absolute():
        exe = Path(shutil.which(str(exe)) or exe).absolute()
    out: list[Path] = []
    if os.path.realpath(exe) == os.path.realpath(sys.executable) or exe == Path(sys.executable):
        out += [Path(sys.prefix), Path(sys.base_prefix)]
    venv = exe.parent.parent
    cfg = venv / "pyvenv.cfg"
    if cfg.is_file():
        out.append(venv)
        try:
            for line in cfg.read_text().splitlines():
                key, _, value = line.partition("=")
                if key.strip() == "home" and value.strip():
                    out.append(Path(value.strip()).parent)
        except OSError:
            pass
    real = Path(os.path.realpath(exe))
    out.append(real.parent.parent)
    seen: list[Path] = []
    for p in out:
        p = Path(os.path.realpath(p))
        if p not in seen and p.is_dir():
            seen.append(p)
    return seen


# ------------------------------------------------------------------------------ work dir
def _prepare_workdir(workdir: Path, mode: str | None) -> None:
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / "tmp").mkdir(exist_ok=True)
    os.chmod(workdir, 0o700)
    if mode != "root":
        return
    for root, dirs, files in os.walk(workdir):
        os.chown(root, NOBODY_UID, NOBODY_UID)
        for name in dirs + files:
            os.chown(os.path.join(root, name), NOBODY_UID, NOBODY_UID, follow_symlinks=False)


def _under(path: str, roots: Iterable[str]) -> bool:
    return any(path == r or path.startswith(r.rstrip("/") + "/") for r in roots)


def _bwrap_argv(bwrap: str, mode: str, workdir: Path, ro_paths: Sequence[Path],
                env: dict[str, str], limits: Limits, argv: Sequence[str], *,
                seccomp_fd: int | None = None) -> list[str]:
    """The bwrap command line (docs/security.md). ``seccomp_fd``: a descriptor holding
    the filter's BPF program (`syscall_filter.memfd`), which the caller passes to bwrap."""
    cmd = [bwrap]
    if mode == "root":
        cmd += ["--unshare-ipc", "--unshare-pid", "--unshare-net", "--unshare-uts",
                "--unshare-cgroup-try"]
    else:
        cmd += ["--unshare-all", "--uid", str(NOBODY_UID), "--gid", str(NOBODY_UID)]
        if _bwrap_disables_userns():
            cmd += ["--unshare-user", "--disable-userns"]
    if seccomp_fd is not None:
        cmd += ["--seccomp", str(seccomp_fd)]
    cmd += ["--die-with-parent", "--new-session", "--clearenv"]
    for name, value in env.items():
        cmd += ["--setenv", name, value]
    cmd += ["--ro-bind", "/usr", "/usr", "--symlink", "usr/lib", "/lib",
            "--symlink", "usr/lib64", "/lib64", "--symlink", "usr/bin", "/bin",
            "--proc", "/proc", "--dev", "/dev"]
    made: set[str] = {"/", "/usr", "/proc", "/dev", "/tmp"}

    def parents(target: str, mounted: Iterable[str]) -> list[str]:
        out = []
        parts = Path(target).parts[1:-1]
        cur = ""
        for part in parts:
            cur += "/" + part
            if cur in made or _under(cur, mounted):
                continue
            made.add(cur)
            out += ["--perms", "0755", "--dir", cur]
        return out

    # /tmp is the work dir's tmp/ (mount points below /tmp land there, on the host)
    work = str(workdir)
    cmd += ["--bind", str(workdir / "tmp"), "/tmp"]
    # read-only binds: drop paths below another bound path (nested binds are redundant)
    ro = sorted({os.path.realpath(p) for p in ro_paths if os.path.isdir(p)})
    ro = [p for p in ro if not _under(p, ["/usr"]) and
          not _under(p, [q for q in ro if q != p])]
    system = [p for p in ("/etc/fonts", "/etc/ld.so.cache", "/var/cache/fontconfig")
              if os.path.exists(p)]
    mounted: list[str] = ["/usr"]
    for p in ro + system:
        cmd += parents(p, mounted)
        cmd += ["--ro-bind", p, p]
        mounted.append(p)
    if os.path.isdir("/etc") and "/etc/mtab" not in mounted:  # 3D renderers ask for the mount list
        cmd += parents("/etc/mtab", mounted) + ["--symlink", "/proc/self/mounts", "/etc/mtab"]
    # the work dir itself, read-write at its own path
    cmd += parents(work, mounted)
    cmd += ["--bind", work, work]
    cmd += ["--perms", "1777", "--size", str(max(1, int(limits.shm_mb)) << 20),
            "--tmpfs", "/dev/shm"]
    cmd += ["--chdir", work]
    if mode == "root":
        cmd += [_setpriv_path() or "/usr/bin/setpriv", f"--reuid={NOBODY_UID}",
                f"--regid={NOBODY_UID}", "--clear-groups", "--no-new-privs", "--"]
    return cmd + [str(a) for a in argv]
