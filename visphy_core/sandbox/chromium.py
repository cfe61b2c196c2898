"""Chromium's processes: the sandbox it runs in, the environment it starts with, and the process
tree the memory watchdog inspects (shared by `visphy_core.sandbox.browser`).

Two containment levels, the strongest available is used:

* ``bwrap`` (visphy runs as root and bubblewrap works, as in the process sandbox): Chromium runs
  under bubblewrap with fresh network, PID, IPC and UTS namespaces, a new root holding read-only
  ``/usr``, ``/etc/fonts`` and ``/etc/chromium*`` only, its private profile and Playwright's
  user-data dir as the only writable places, and drops to uid/gid 65534 (``setpriv``, no
  capabilities, ``no_new_privs``). A renderer exploit then finds no network, no host files and
  no privileges. (Chromium's own sandbox stays off, as Playwright runs it as root.)
  bwrap also loads the process sandbox's seccomp filter (`visphy_core.sandbox.syscall_filter`)
  before it starts ``setpriv``: no ``unshare``/``setns``/``clone`` into a new namespace (so no
  nested user namespace with a full capability set), no ``ptrace``, mounts, keyrings, ``bpf``,
  ``perf_event_open``, ``userfaultfd`` or ``io_uring``. Chromium runs with ``--no-sandbox``
  (Playwright's default for a root caller), so it creates no namespaces of its own and the
  filter costs it nothing. ``--disable-userns`` is not used: it needs ``--unshare-user``, which
  for a root caller would map the sandbox's uid onto root (see `visphy_core.sandbox.process`).
* ``netns``: Chromium in a fresh, empty network namespace (``unshare -n`` / ``unshare -rn``).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

_NETNS_PROBE: dict = {}
_BWRAP_PROBE: dict = {}
#: The uid Chromium runs as under bubblewrap (Debian's nobody).
CHROMIUM_UID = 65534


def bwrap_for_chromium() -> tuple[str | None, str]:
    """(bwrap path, note) when Chromium can run under bubblewrap as uid 65534, else (None, why).

    Needs a root caller (bwrap builds the namespaces, ``setpriv`` drops privileges inside) and a
    working bubblewrap: the process sandbox's probe decides. Probed once per process."""
    if "result" not in _BWRAP_PROBE:
        from visphy_core.sandbox import process

        ok, why = process.isolation_available()
        bwrap, setpriv = shutil.which("bwrap"), shutil.which("setpriv")
        if os.geteuid() != 0:
            result = (None, "not root: Chromium runs in a network namespace only")
        elif not ok or bwrap is None or setpriv is None:
            result = (None, why if not ok else "bwrap or setpriv missing")
        else:
            result = (bwrap, why)
        _BWRAP_PROBE["result"] = result
    return _BWRAP_PROBE["result"]


def _dirs_for(path: Path) -> list[str]:
    """bwrap arguments creating every ancestor of ``path`` traversable (bwrap would make them
    0700 and root-owned, which uid 65534 cannot cross)."""
    out: list[str] = []
    for parent in reversed(path.parents):
        if str(parent) != "/":
            out += ["--perms", "1777" if str(parent) == "/tmp" else "0755", "--dir", str(parent)]
    return out


#: The seccomp filter's BPF program, written by `bwrap_launcher` next to the profile.
SECCOMP_FILE = "chromium-seccomp.bpf"


def write_seccomp_filter(directory: Path) -> Path:
    """Write the seccomp filter (`syscall_filter.bpf_program`) to ``directory`` (root-owned and
    not writable by uid 65534: the launcher reads it as root each time it starts bwrap)."""
    from visphy_core.sandbox import syscall_filter

    path = directory / SECCOMP_FILE
    tmp = directory / (SECCOMP_FILE + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(syscall_filter.bpf_program())
    os.replace(tmp, path)
    return path


#: /bin/sh lines for a launcher, before its ``exec``: Chromium honours only the last
#: ``--disable-features`` (and ``--enable-features``) of its command line, and Playwright passes
#: its own list before the pool's arguments, so each list is merged into one switch (all the
#: values, in order) at the end of ``"$@"``: Playwright's features and the pool's alike apply.
MERGE_FEATURES_SH = """dis=""; ena=""
for a in "$@"; do
  case "$a" in
    --disable-features=*) dis="${dis:+$dis,}${a#--disable-features=}";;
    --enable-features=*) ena="${ena:+$ena,}${a#--enable-features=}";;
  esac
done
for a in "$@"; do
  shift
  case "$a" in --disable-features=*|--enable-features=*) ;; *) set -- "$@" "$a";; esac
done
if [ -n "$dis" ]; then set -- "$@" "--disable-features=$dis"; fi
if [ -n "$ena" ]; then set -- "$@" "--enable-features=$ena"; fi
"""


def bwrap_launcher(bwrap: str, executable: str, profile: Path) -> str:
    """The body of a /bin/sh launcher that execs ``executable "$@"`` under bubblewrap as uid
    65534, with the seccomp filter. ``profile`` (Chromium's HOME, owned by 65534) is bound
    writable; so is the ``--user-data-dir`` Playwright passes, handed to 65534 by the script.
    Writes the filter's BPF program to ``profile``'s parent (`write_seccomp_filter`), which the
    script passes to bwrap as descriptor 9. Raises `syscall_filter.FilterUnavailable` when the
    filter cannot be built (`bwrap_for_chromium` has already checked that it can)."""
    bpf = write_seccomp_filter(profile.parent)
    static = [bwrap, "--unshare-net", "--unshare-pid", "--unshare-ipc", "--unshare-uts",
              "--die-with-parent", "--new-session", "--seccomp", "9",
              "--ro-bind", "/usr", "/usr", "--symlink", "usr/lib", "/lib",
              "--symlink", "usr/lib64", "/lib64", "--symlink", "usr/bin", "/bin",
              "--symlink", "usr/sbin", "/sbin",
              "--perms", "0755", "--dir", "/etc", "--perms", "0755", "--dir", "/var",
              "--perms", "0755", "--dir", "/var/cache"]
    for path in ("/etc/fonts", "/etc/chromium", "/etc/chromium.d", "/etc/ld.so.cache",
                 "/var/cache/fontconfig"):
        static += ["--ro-bind-try", path, path]
    static += ["--proc", "/proc", "--dev", "/dev", "--tmpfs", "/dev/shm",
               *_dirs_for(profile), "--bind", str(profile), str(profile)]
    drop = ["--", shutil.which("setpriv") or "/usr/bin/setpriv", f"--reuid={CHROMIUM_UID}",
            f"--regid={CHROMIUM_UID}", "--clear-groups", "--no-new-privs", "--", executable]
    q = " ".join
    return f"""#!/bin/sh
echo $$ > "$VISPHY_CHROMIUM_PIDFILE"
{MERGE_FEATURES_SH}udd=""
for a in "$@"; do case "$a" in --user-data-dir=*) udd="${{a#--user-data-dir=}}";; esac; done
extra=""
if [ -n "$udd" ]; then
  case "$udd" in *[!A-Za-z0-9_./-]*) echo "visphy: unexpected user-data-dir $udd" >&2; exit 2;; esac
  chown -R {CHROMIUM_UID}:{CHROMIUM_UID} "$udd"
  p=""
  for c in $(dirname "$udd" | tr / ' '); do
    p="$p/$c"
    if [ "$p" = /tmp ]; then m=1777; else m=0755; fi
    extra="$extra --perms $m --dir $p"
  done
  extra="$extra --bind $udd $udd"
fi
exec {q(sh_quote(a) for a in static)} $extra {q(sh_quote(a) for a in drop)} "$@" \
  9<{sh_quote(str(bpf))} 2>>"$VISPHY_CHROMIUM_STDERR"
"""


def netns_prefix() -> tuple[list[str] | None, str]:
    """The command prefix that runs a program in a fresh, empty network namespace, and a note.

    Probed once per process: ``unshare -n`` (root) or ``unshare -rn`` (user namespace), accepted
    only if the namespace really holds nothing but a loopback interface. (None, why) when the
    kernel or the container refuses."""
    if "result" in _NETNS_PROBE:
        return _NETNS_PROBE["result"]
    unshare = shutil.which("unshare") or "/usr/bin/unshare"
    candidates = ([[unshare, "-n", "--"]] if os.geteuid() == 0 else []) + [[unshare, "-rn", "--"]]
    why = f"{unshare} not found" if not Path(unshare).exists() else ""
    result: tuple[list[str] | None, str] = (None, why)
    if Path(unshare).exists():
        for prefix in candidates:
            try:
                proc = subprocess.run(prefix + ["cat", "/proc/self/net/dev"], capture_output=True,
                                      text=True, timeout=10, env={"PATH": "/usr/bin:/bin"})
            except (OSError, subprocess.SubprocessError) as exc:
                why = f"{' '.join(prefix)} failed: {exc}"
                continue
            ifaces = {line.split(":", 1)[0].strip() for line in proc.stdout.splitlines()[2:]
                      if ":" in line}
            if proc.returncode == 0 and ifaces <= {"lo"}:
                result = (prefix, " ".join(prefix[:-1]))
                break
            why = (f"{' '.join(prefix[:-1])} refused: "
                   f"{(proc.stderr.strip() or f'interfaces {sorted(ifaces)}')[:200]}")
        else:
            result = (None, why)
    _NETNS_PROBE["result"] = result
    return result


# ------------------------------------------------------------------------- process inspection

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def _children(pid: int) -> list[int]:
    out: list[int] = []
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tasks:
        try:
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                out += [int(x) for x in f.read().split()]
        except (OSError, ValueError):
            pass
    return out


def descendants(pid: int) -> list[int]:
    seen, todo = [], [pid]
    while todo:
        for child in _children(todo.pop()):
            if child not in seen:
                seen.append(child)
                todo.append(child)
    return seen


def _proc_type(pid: int) -> str:
    # Chromium rewrites its children's command lines (one string, spaces, no NULs).
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            m = re.search(rb"(?:^|[\s\0])--type=([\w-]+)", f.read())
    except OSError:
        return ""
    return m.group(1).decode() if m else "browser"


def rss_bytes(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return 0


@dataclass
class ChromiumProcess:
    """One launched browser: Playwright's handle, its process id, its stderr log."""

    browser: object
    pid: int | None
    stderr: Path
    kinds: dict = field(default_factory=dict)  # pid -> process type ("renderer", "gpu-process")

    def processes(self, kinds: tuple[str, ...]) -> list[int]:
        if self.pid is None:
            return []
        out = []
        for pid in descendants(self.pid):
            if self.kinds.get(pid, "browser") == "browser":  # a fresh fork is renamed later
                self.kinds[pid] = _proc_type(pid)
            if self.kinds[pid] in kinds:
                out.append(pid)
        if len(self.kinds) > 500:
            self.kinds.clear()
        return out

    def stderr_size(self) -> int:
        try:
            return self.stderr.stat().st_size
        except OSError:
            return 0

    def stderr_since(self, offset: int, limit: int = 1 << 20) -> str:
        try:
            with open(self.stderr, "rb") as f:
                f.seek(offset)
                return f.read(limit).decode(errors="replace")
        except OSError:
            return ""


def kill_all(pids) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def sh_quote(arg: str) -> str:
    return "'" + arg.replace("'", "'\"'\"'") + "'"


def chromium_env(home: Path | None = None) -> dict[str, str]:
    """Chromium's environment: an allow-list (no API keys or tokens), with a private HOME."""
    from visphy_core.infra.secrets import is_secret_name, secret_values

    keep = ("PATH", "LANG", "LC_ALL", "TZ", "FONTCONFIG_PATH", "FONTCONFIG_FILE")
    secrets = secret_values()
    env = {k: v for k, v in os.environ.items()
           if k in keep and not is_secret_name(k) and v not in secrets}
    env.setdefault("PATH", "/usr/local/bin:/usr/bin:/bin")
    env.setdefault("TZ", "UTC")
    if home is not None:
        env["HOME"] = str(home)
        env["XDG_CONFIG_HOME"] = str(home / ".config")
        env["XDG_CACHE_HOME"] = str(home / ".cache")
        env["TMPDIR"] = str(home)
    return env
