"""Advisory file locks for what runs, studies and commands share in one home (``paths.root``).

A lock is an ``flock`` on a small lock file beside the thing it guards (``<thing>.lock``):
the kernel releases it when the holder exits, however it exits (a killed process never
leaves a stale lock), and any number of processes wait on it without polling. What must
happen once per home — MLflow's schema, the benchmark's catalogue, one scene's render —
happens under the lock, and whoever comes next finds it done and only reads.

``flock`` serialises processes on one machine, and across machines on file systems that
implement it (local disks, Lustre, NFSv4 with lock support); docs/reliability.md says what to
do where they do not (a tracking server for MLflow).
"""

from __future__ import annotations

import fcntl
import os
import sys
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

#: After this many seconds of waiting, a waiter says once on stderr what it waits for.
SAY_AFTER_S = 10.0


def lock_path(guarded: str | Path) -> Path:
    """The lock file of ``guarded``: ``<guarded>.lock`` beside it (a dot file inside a
    folder for a folder)."""
    guarded = Path(guarded)
    return guarded / ".lock" if guarded.is_dir() else guarded.with_name(f"{guarded.name}.lock")


#: Locks this process holds: path → (thread lock, depth). A lock is re-entrant within the
#: process (a function holding it may call another that takes it) and held by one thread at a
#: time; across processes it is the ``flock``.
_HELD: dict[str, list] = {}
_HELD_GUARD = threading.Lock()


@contextmanager
def exclusive(path: str | Path, what: str = "") -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``path`` (created, with its folder, when missing) for the
    ``with`` block. Blocks until the lock is free; after `SAY_AFTER_S` seconds of waiting it
    prints one line naming ``what`` (default: the lock file) so a waiting command never looks
    hung. Re-entrant within a process."""
    path = Path(path)
    key = os.path.abspath(path)
    with _HELD_GUARD:
        entry = _HELD.setdefault(key, [threading.RLock(), 0, None])
    with entry[0]:
        if entry[1] == 0:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            try:
                _acquire(fd, what or str(path))
            except BaseException:
                os.close(fd)
                raise
            entry[2] = fd
        entry[1] += 1
        try:
            yield
        finally:
            entry[1] -= 1
            if entry[1] == 0:
                fd, entry[2] = entry[2], None
                try:
                    fcntl.flock(fd, fcntl.LOCK_UN)
                finally:
                    os.close(fd)


def _acquire(fd: int, what: str) -> None:
    """A blocking ``flock``; a timer says once what it waits for if the wait is long."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return
    except BlockingIOError:
        pass
    notice = threading.Timer(SAY_AFTER_S, lambda: print(
        f"waiting for another visphy process to finish with {what}", file=sys.stderr,
        flush=True))
    notice.daemon = True
    notice.start()
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
    finally:
        notice.cancel()
