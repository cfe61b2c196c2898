"""How SIGINT/SIGTERM close a run (`visphy_core.execute.run`): `RunInterrupted` raised in the
main thread while scenes run, and the signals held while the run's files are written."""

from __future__ import annotations

import os
import signal
import threading
from contextlib import contextmanager
from typing import Iterator


class RunInterrupted(SystemExit):
    """SIGINT/SIGTERM during a run. A `SystemExit` (exit status 128 + signal number), so no
    ``except Exception`` in a scene's code swallows it and the CLI exits without a traceback."""

    def __init__(self, signum: int):
        super().__init__(128 + signum)
        self.signum = signum


@contextmanager
def _signals_close_the_run() -> Iterator[None]:
    """SIGINT/SIGTERM raise `RunInterrupted` in the main thread (the scene in progress is
    abandoned: it is redone on resume); a second signal while the run closes exits at once."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    state: dict[str, int | None] = {"signum": None}

    def handler(signum, frame):
        if state["signum"] is None:
            state["signum"] = signum
            raise RunInterrupted(signum)
        os._exit(128 + signum)

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        state["signum"] = state["signum"] or -1  # closing: a further signal exits at once
        for sig, old in previous.items():
            signal.signal(sig, old)


@contextmanager
def _deferred_signals() -> Iterator[list[int]]:
    """Hold SIGINT/SIGTERM while the run's files are closed; re-delivered afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    pending: list[int] = []
    previous = {sig: signal.signal(sig, lambda s, f: pending.append(s))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield pending
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
