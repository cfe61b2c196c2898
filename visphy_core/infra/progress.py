"""Progress for a log: when stderr is no terminal (a pipe, a file, CI, ``nohup``) the live bars
draw nothing, so work reports itself as plain lines instead, with no terminal codes.

`PlainLines` bounds how often they come: a line per key (a stage, a loop) at most every
`EVERY` seconds, and a heartbeat when nothing was written for `QUIET` seconds while work goes
on, so a log is never silent longer than that. `track` wraps a loop: rich's transient bar on a
terminal, these lines elsewhere."""

from __future__ import annotations

import math
import sys
import threading
import time
from typing import Callable, Iterable, Iterator, TextIO, TypeVar

T = TypeVar("T")

#: seconds between two lines of one key (a stage, a loop)
EVERY = 5.0
#: seconds of silence after which a heartbeat line is written while work goes on
QUIET = 10.0


def output_columns(off_terminal: int) -> int:
    """Columns to print tables in: ``COLUMNS`` when set, the terminal's when stdout is one,
    else ``off_terminal`` (a log or a pipe)."""
    import os
    import shutil

    columns = os.environ.get("COLUMNS", "")
    if columns.isdigit() and int(columns) > 0:
        return int(columns)
    if sys.stdout.isatty():
        return shutil.get_terminal_size().columns
    return off_terminal


def on_terminal(stream: TextIO | None = None) -> bool:
    """Whether ``stream`` (default: stderr, where progress goes) is a terminal."""
    stream = stream if stream is not None else sys.stderr
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``1 h 02 min``: a wall time or an ETA for people."""
    seconds = max(0.0, seconds)
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes, secs = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


def rate_and_eta(done: int, total: int, elapsed: float) -> str:
    """``0.42/s · ETA 12 s`` (per minute when slower than one a second); nothing before the
    first item is done."""
    if done <= 0 or elapsed <= 0:
        return ""
    per_s = done / elapsed
    rate = (f"{per_s:.0f}/s" if per_s >= 10 else f"{per_s:.2g}/s" if per_s >= 1
            else f"{per_s * 60:.0f}/min" if per_s * 60 >= 10 else f"{per_s * 60:.2g}/min")
    left = max(0, total - done)
    eta = f" · ETA {duration(left / per_s)}" if left and not math.isinf(per_s) else ""
    return f"{rate}{eta}"


class PlainLines:
    """Writes progress lines to ``out`` (default stderr), at most one per key every ``every``
    seconds (`emit`; ``force`` for a line that must show, a stage's last one), and calls
    ``heartbeat`` for a line when nothing was written for ``quiet`` seconds (`tick`, run by a
    daemon thread between `start` and `stop`). Thread-safe; the clock is injectable so the
    pacing is tested without sleeping."""

    def __init__(self, heartbeat: Callable[[], str | None] | None = None,
                 out: TextIO | None = None, every: float = EVERY, quiet: float = QUIET,
                 clock: Callable[[], float] = time.monotonic):
        self.heartbeat = heartbeat
        self.out = out
        self.every, self.quiet, self.clock = every, quiet, clock
        self._last: dict[str, float] = {}
        #: a key's latest line held back by the pace, written by `tick` once it is due
        self._pending: dict[str, str] = {}
        self._last_any = clock()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _write(self, text: str) -> None:
        out = self.out if self.out is not None else sys.stderr
        print(text, file=out, flush=True)

    def emit(self, key: str, text: str, force: bool = False) -> bool:
        """Write ``text`` unless ``key`` had a line less than ``every`` seconds ago."""
        with self._lock:
            now = self.clock()
            if not force and now - self._last.get(key, -math.inf) < self.every:
                self._pending[key] = text
                return False
            self._pending.pop(key, None)
            self._last[key] = self._last_any = now
            self._write(text)
            return True

    def tick(self) -> bool:
        """The lines the pace held back, once their key is due; else the heartbeat, when due:
        ``heartbeat()``'s line if nothing was written for ``quiet`` seconds (None from it:
        nothing to say, no line)."""
        with self._lock:
            now = self.clock()
            due = [k for k in self._pending if now - self._last.get(k, -math.inf) >= self.every]
            for key in due:
                self._last[key] = self._last_any = now
                self._write(self._pending.pop(key))
            if due:
                return True
            if self.heartbeat is None or now - self._last_any < self.quiet:
                return False
            text = self.heartbeat()
            if not text:
                return False
            self._last_any = now
            self._write(text)
            return True

    def start(self) -> "PlainLines":
        def run() -> None:
            while not self._stop.wait(1.0):
                try:
                    self.tick()
                except Exception:  # noqa: BLE001 - a progress line never stops the work
                    pass

        self._thread = threading.Thread(target=run, name="visphy-progress", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None


def track(iterable: Iterable[T], total: int, description: str, enabled: bool = True,
          out: TextIO | None = None) -> Iterator[T]:
    """``iterable``, reporting ``n/total`` as it goes: rich's transient bar when stderr is a
    terminal, else plain lines (``description n/total · rate · ETA``, paced by `PlainLines`, a
    last line when it ends). Nothing when not ``enabled``."""
    if not enabled:
        yield from iterable
        return
    if on_terminal(out):
        from rich.progress import track as rich_track

        yield from rich_track(iterable, total=total, description=description, transient=True)
        return
    started = time.monotonic()
    done = 0

    def line(still: bool = False) -> str:
        elapsed = time.monotonic() - started
        pace = rate_and_eta(done, total, elapsed)
        return (f"{description}: {done}/{total}" + (f" · {pace}" if pace else "")
                + f" · {duration(elapsed)} elapsed" + (" · still working" if still else ""))

    lines = PlainLines(heartbeat=lambda: line(still=True), out=out)
    lines.emit(description, line(), force=True)
    lines.start()
    try:
        for item in iterable:
            yield item
            done += 1
            lines.emit(description, line(), force=done >= total)
    finally:
        lines.stop()
