"""The resource limits of a sandboxed program (`visphy_core.sandbox.process.run_sandboxed`).

`Limits` and the rlimits it becomes (set between fork and exec), the work-dir quota's measure
(`disk_usage`), and the limit an error message points at (`limit_from_text`, `describe_limit`).
Each limit and how it is enforced and tested: docs/security.md, the process sandbox section.
"""

from __future__ import annotations

import math
import os
import resource
from dataclasses import dataclass
from pathlib import Path

#: How often the disk watchdog measures the work dir (seconds).
DISK_POLL_S = 0.2

_MEMORY_PATTERNS = ("MemoryError", "bad_alloc", "Cannot allocate memory", "out of memory",
                    "Out of memory")
_FSIZE_PATTERNS = ("File too large", "[Errno 27]")
_NPROC_PATTERNS = ("Resource temporarily unavailable", "BlockingIOError", "[Errno 11]",
                   "fork: retry", "Cannot fork", "can't start new thread")


@dataclass
class Limits:
    """Resource limits of one sandboxed run (seconds, MiB, count)."""

    wall_s: float = 120.0
    cpu_s: float = 120.0
    memory_mb: int = 4096       # address space (RLIMIT_AS), not resident memory
    file_size_mb: int = 1024    # largest single file the program may write
    disk_mb: int = 2048         # total allocated size of the work dir (watchdog)
    max_files: int = 20000      # entries in the work dir (watchdog)
    processes: int = 256        # processes/threads of uid 65534 (RLIMIT_NPROC)
    shm_mb: int = 64            # size of the private /dev/shm tmpfs


# ------------------------------------------------------------------------------ rlimits
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


# ------------------------------------------------------------------------------ disk watchdog
def disk_usage(root: Path, stop_at: tuple[int, int] | None = None) -> tuple[int, int]:
    """(allocated bytes, entries) below ``root``, without following links; stops early once
    either exceeds ``stop_at``."""
    total, entries = 0, 0
    stack = [str(root)]
    while stack:
        path = stack.pop()
        try:
            it = os.scandir(path)
        except OSError:
            continue
        with it:
            for entry in it:
                entries += 1
                try:
                    st = entry.stat(follow_symlinks=False)
                except OSError:
                    continue
                total += st.st_blocks * 512
                if entry.is_dir(follow_symlinks=False):
                    stack.append(entry.path)
                if stop_at and (total > stop_at[0] or entries > stop_at[1]):
                    return total, entries
    return total, entries


def limit_from_text(text: str) -> str | None:
    """The resource limit an error message points at (``"memory"``, ``"file_size"``,
    ``"processes"``) or None: for runners that catch the program's exception themselves."""
    if any(p in text for p in _MEMORY_PATTERNS):
        return "memory"
    if any(p in text for p in _FSIZE_PATTERNS):
        return "file_size"
    if any(p in text for p in _NPROC_PATTERNS):
        return "processes"
    return None


def describe_limit(hit: str | None, limits: Limits, detail: str = "") -> str | None:
    """The message of a resource-limit hit (``memory``, ``file_size``, ``disk``, ``processes``:
    the program's ``resource_limit``), the same for every engine; None for any other hit."""
    what = f": {detail}" if detail else ""
    return {
        "memory": f"memory limit ({limits.memory_mb} MB) exceeded{what}",
        "file_size": f"file size limit ({limits.file_size_mb} MB) exceeded{what}",
        "disk": (f"disk quota of the work dir ({limits.disk_mb} MB, {limits.max_files} files) "
                 f"exceeded{what}"),
        "processes": f"process limit ({limits.processes} processes) reached{what}",
    }.get(hit or "")
