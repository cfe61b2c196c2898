"""Keep a run's resident memory near what it holds (glibc's allocator, Linux).

A run scores scenes on several threads, and every scene allocates and frees clips and metric
buffers of one to a few hundred megabytes. glibc gives each thread an arena of its own and,
once a large block has been freed, raises its threshold for serving blocks from the operating
system directly (``mmap``) up to 32 MiB; blocks below it then come from the arenas, whose freed
pages stay in the process. Measured (oracle × threejs, default suite, 2 workers, idle 2-core
machine): a whole `visphybench` run peaked at 8.7 GiB; back to back on the same scenes, 21 of
them peaked at 4.9 GiB without the trim below and 3.3 GiB with it (+4 % CPU), 42 of them at
6.3 and 4.7 GiB (+12 % time: freed pages are faulted in again by the next scene). A fixed low
``mmap`` threshold (``MALLOC_MMAP_THRESHOLD_=262144``) held 2.9 GiB but cost 39 % more wall time
in page faults.

`release_free_memory` hands the arenas' free pages back (``malloc_trim(0)``); the run calls it
after every scene. Nothing here changes a value that any computation sees. Where the C library
is not glibc (musl, macOS), or with ``VISPHY_MALLOC_TRIM=0``, it does nothing.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
from functools import lru_cache

_LOCK = threading.Lock()
#: ``0`` turns the trim off (the allocator then keeps freed pages, as glibc does by default)
TRIM_ENV = "VISPHY_MALLOC_TRIM"


@lru_cache(maxsize=1)
def _glibc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        lib = ctypes.CDLL("libc.so.6")
    except OSError:
        return None
    if not hasattr(lib, "malloc_trim"):  # pragma: no cover - not glibc
        return None
    lib.malloc_trim.argtypes = [ctypes.c_size_t]
    lib.malloc_trim.restype = ctypes.c_int
    return lib


def release_free_memory() -> bool:
    """Return the allocator's free pages to the operating system; True when some were."""
    lib = _glibc()
    if lib is None or os.environ.get(TRIM_ENV, "1").strip() == "0":
        return False
    with _LOCK:  # one trim at a time: it walks every arena under that arena's lock
        return bool(lib.malloc_trim(0))
