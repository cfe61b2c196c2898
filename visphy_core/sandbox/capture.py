"""Bounded capture of a sandboxed program's output pipes, and feeding its stdin.

`_Capture` drains one pipe on a thread, keeping the first `_HEAD_BYTES` and the last bytes up to
`MAX_OUTPUT_BYTES` (the middle replaced by a one-line marker), and never blocks past the kill
(docs/security.md, the process sandbox section).
"""

from __future__ import annotations

import os
import select
import threading

#: Bytes of stdout (and, separately, of stderr) kept per run: the first `_HEAD_BYTES` and the last
#: ``MAX_OUTPUT_BYTES - _HEAD_BYTES``.
MAX_OUTPUT_BYTES = 1 << 20
_HEAD_BYTES = 64 << 10


class _Capture:
    """Drain one pipe (a raw fd we own) to EOF or until told to stop, keeping the head and the
    tail (bounded memory). Never blocks past `stop`: the fd is polled with a short timeout."""

    def __init__(self, fd: int, cap: int = MAX_OUTPUT_BYTES):
        self.fd = fd
        os.set_blocking(fd, False)
        self.head = bytearray()
        self.tail = bytearray()
        self.dropped = 0
        self.head_cap = min(_HEAD_BYTES, cap)
        self.tail_cap = cap - self.head_cap
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _take(self, chunk: bytes) -> None:
        room = self.head_cap - len(self.head)
        if room > 0:
            self.head += chunk[:room]
            chunk = chunk[room:]
        if chunk:
            self.tail += chunk
            excess = len(self.tail) - self.tail_cap
            if excess > 0:
                del self.tail[:excess]
                self.dropped += excess

    def _run(self) -> None:
        poller = select.poll()
        poller.register(self.fd, select.POLLIN | select.POLLHUP | select.POLLERR)
        while True:
            try:
                events = poller.poll(100)
            except InterruptedError:
                continue
            except OSError:
                return
            if not events:
                if self.stopping.is_set():
                    return
                continue
            try:
                chunk = os.read(self.fd, 65536)
            except BlockingIOError:
                continue
            except OSError:
                return
            if not chunk:
                return
            self._take(chunk)

    def text(self, join_timeout: float) -> str:
        self.stopping.set()
        self.thread.join(join_timeout)
        try:
            os.close(self.fd)
        except OSError:
            pass
        middle = (f"\n[... {self.dropped} bytes of output dropped ...]\n".encode()
                  if self.dropped else b"")
        return (bytes(self.head) + middle + bytes(self.tail)).decode("utf-8", "replace")


def _feed(fd: int, data: bytes) -> None:
    try:
        view = memoryview(data)
        while view:
            n = os.write(fd, view)
            view = view[n:]
    except OSError:
        pass
    finally:
        try:
            os.close(fd)
        except OSError:
            pass
