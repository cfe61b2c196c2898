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


@contextmanager
def exclusive(path: str | Path, what: str = "") -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``path`` (created, with its folder, when missing) for the
    ``with`` block. Blocks until the lock is free; after `SAY_AFTER_S` seconds of waiting it
    prints one line naming ``what`` (default: the lock file) so a waiting command never looks
    hung."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        _acquire(fd, what or str(path))
        try:
            yield
        finally:
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
