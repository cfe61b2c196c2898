"""Keep a run's resident memory near what it holds (CPython's garbage collector, glibc's
allocator, Linux).

A run scores scenes on several threads, and every scene allocates and frees clips and metric
buffers of one to a few hundred megabytes. Three things kept memory that no scene held any more:

* **Reference cycles.** What a scene drops inside a cycle is freed only by CPython's cyclic
  garbage collector, and its full collections come rarely in a run: CPython starts one only
  once the objects that survived since the last one number a quarter of the long-lived ones,
  and torch alone brings hundreds of thousands of those. Playwright's page listeners and the
  stack traces it captures for its calls hold each page's capture in such cycles (the sandbox
  now hands its captures over detached, `visphy_core.sandbox.browser.PageCapture.detached`),
  as does any exception caught with its traceback's frames. Measured (the default model and
  engine, default suite, 2 workers, 40 2D scenes): lists of frames no scene held grew by 14 MiB per
  scene, to 0.6 GiB; the memory in use (glibc's count) from 0.74 to 1.25 GiB.
  `release_free_memory` runs a full collection first (about 0.2 s with the metric models
  loaded; ``VISPHY_SCENE_GC=0`` turns it off).
* **Per-thread arenas.** glibc gives each thread an arena of its own (up to 8 per core), and
  memory freed in one arena serves only the threads of that arena; a run's scenes move from
  thread to thread (`visphy_core.execute.scheduler`: 2 × workers + 1 of them), so each arena grew to
  the largest scene it had seen. `limit_arenas` caps them (``VISPHY_MALLOC_ARENAS``, default
  `DEFAULT_ARENAS`; glibc's own ``MALLOC_ARENA_MAX``, when set, wins); it must run before the
  run's threads start (`visphy_core.execute.scheduler.pin_torch_threads` calls it).
* **Freed pages kept resident.** Once a large block has been freed, glibc serves blocks up to
  that size (≤ 32 MiB) from the arenas instead of ``mmap``, and their freed pages stay in the
  process. `release_free_memory` hands them back (``malloc_trim(0)``) after every scene.
  Measured before the two fixes above, back to back on the same scenes: 21 scenes peaked at
  4.9 GiB without the trim and 3.3 GiB with it (+4 % CPU). A fixed low ``mmap`` threshold
  (``MALLOC_MMAP_THRESHOLD_=262144``) held 2.9 GiB but cost 39 % more wall time in page faults.

  Between two scenes' ends, `BudgetTrim` (a thread the scene scheduler runs) trims whenever
  the process's RSS is above a budget (``VISPHY_RSS_BUDGET_MB``, default
  `DEFAULT_BUDGET_MB`) and grew by `BudgetTrim.STEP` since the last trim: a scene's freed
  buffers are faulted in again by the next one, so a trim costs time, and it is paid only
  above the budget.

Nothing here changes a value that any computation sees. Where the C library is not glibc (musl,
macOS) the allocator settings do nothing; ``VISPHY_MALLOC_TRIM=0`` turns every trim off.
"""

from __future__ import annotations

import ctypes
import gc
import os
import sys
import threading
import time
from functools import lru_cache

_LOCK = threading.Lock()
#: ``0`` turns the trim off (the allocator then keeps freed pages, as glibc does by default)
TRIM_ENV = "VISPHY_MALLOC_TRIM"
#: ``0`` turns the full garbage collection after each scene off
GC_ENV = "VISPHY_SCENE_GC"
#: the most glibc arenas (``0``: glibc's default, 8 per core)
ARENAS_ENV = "VISPHY_MALLOC_ARENAS"
#: One arena: memory freed by one scene's thread serves the next scene's, whichever thread it
#: runs on. The threads that allocate at once are few (the scenes' and the browser pool's;
#: torch runs one intra-op thread, `visphy_core.execute.scheduler.pin_torch_threads`) and glibc's
#: per-thread caches serve small blocks without the arena's lock.
DEFAULT_ARENAS = 1
#: the RSS (MiB) above which `BudgetTrim` hands free pages back (``0``: never)
BUDGET_ENV = "VISPHY_RSS_BUDGET_MB"
#: The run's own process at rest holds about 1.3 GiB (Python, torch and its libraries, the metric
#: models, a 128 MiB per-frame cache); Chromium and Playwright's driver beside it peak at 1.1–1.2
#: GiB. Measured (the default model and engine, default suite, 2 workers, 21 scenes, 3 of them 3D,
#: per-frame cache 128 MiB, a busy machine): the run process peaked at 2.10 GiB without the budget
#: and 1.87 with it (tree 3.11 → 2.91 GiB), for +10 % CPU: the pages a trim returns are faulted in
#: again (106 trims returned 20 GiB in all).
DEFAULT_BUDGET_MB = 1600
#: mallopt's parameter number for the arena limit (malloc.h: ``M_ARENA_MAX``)
_M_ARENA_MAX = -8


@lru_cache(maxsize=1)
def _glibc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        lib = ctypes.CDLL("libc.so.6")
    except OSError:
        return None
    if not hasattr(lib, "malloc_trim") or not hasattr(lib, "mallopt"):  # pragma: no cover
        return None  # not glibc
    lib.malloc_trim.argtypes = [ctypes.c_size_t]
    lib.malloc_trim.restype = ctypes.c_int
    lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    lib.mallopt.restype = ctypes.c_int
    return lib


def _env_off(name: str) -> bool:
    return os.environ.get(name, "1").strip() == "0"


def limit_arenas() -> int | None:
    """Cap glibc's arenas at ``$VISPHY_MALLOC_ARENAS`` (default `DEFAULT_ARENAS`); returns the
    cap set, or None where nothing was set (not glibc, ``0``, or ``MALLOC_ARENA_MAX`` in the
    environment: glibc applied it at start-up). Threads that already have an arena keep it:
    call this before the run's threads start."""
    lib = _glibc()
    if lib is None or "MALLOC_ARENA_MAX" in os.environ:
        return None
    raw = os.environ.get(ARENAS_ENV, "").strip()
    try:
        n = int(raw) if raw else DEFAULT_ARENAS
    except ValueError:
        raise ValueError(f"${ARENAS_ENV} must be a whole number (0: glibc's default), "
                         f"not {raw!r}") from None
    if n <= 0:
        return None
    return n if lib.mallopt(_M_ARENA_MAX, n) == 1 else None


def _trim() -> bool:
    lib = _glibc()
    if lib is None or _env_off(TRIM_ENV):
        return False
    with _LOCK:  # one trim at a time: it walks every arena under that arena's lock
        return bool(lib.malloc_trim(0))


def release_free_memory() -> bool:
    """Free what only reference cycles still hold (a full garbage collection), then return the
    allocator's free pages to the operating system; True when some pages were returned."""
    if not _env_off(GC_ENV):
        gc.collect()
    return _trim()


_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int | None:
    """This process's resident memory (Linux: /proc/self/statm), None where unknown."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


def budget_bytes() -> int:
    """``$VISPHY_RSS_BUDGET_MB`` in bytes (default `DEFAULT_BUDGET_MB`; 0: no budget)."""
    raw = os.environ.get(BUDGET_ENV, "").strip()
    try:
        return max(0, int(float(raw) * 2**20)) if raw else DEFAULT_BUDGET_MB * 2**20
    except ValueError:
        raise ValueError(f"${BUDGET_ENV} must be a number of MiB (0: none), not {raw!r}") from None


class BudgetTrim:
    """A daemon thread that returns the allocator's free pages (``malloc_trim``) when this
    process's RSS is above ``budget`` bytes (default `budget_bytes`) and has grown by ``step``
    bytes (default `STEP`) since the last trim (or since the lowest RSS seen after it); it
    looks every ``every_s`` seconds and trims at most once every `MIN_WAIT_S`. Between two
    trims the RSS thus stays within ``step`` of what the last one left, which is what was in
    use then; a trim that finds little to give back (what is resident is in use) is not
    repeated until the RSS grows again. The pages a trim gives back are faulted in again by
    later allocations: that is its cost, paid only above the budget. `start` does nothing
    (returns False) without glibc, Linux's RSS, a budget, or with ``VISPHY_MALLOC_TRIM=0``.
    ``looks``, ``trims`` and ``returned`` (bytes) count what it did."""

    STEP = 128 * 2**20
    MIN_WAIT_S = 1.0

    def __init__(self, budget: int | None = None, every_s: float = 0.2,
                 step: int | None = None):
        self.budget = budget_bytes() if budget is None else int(budget)
        self.every_s = every_s
        self.step = self.STEP if step is None else int(step)
        self.looks = 0
        self.trims = 0
        self.returned = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> bool:
        if (self.budget <= 0 or _glibc() is None or _env_off(TRIM_ENV)
                or rss_bytes() is None):
            return False
        if self._thread is None:
            self._thread = threading.Thread(target=self._watch, name="visphy-budget-trim",
                                            daemon=True)
            self._thread.start()
        return True

    def stop(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _watch(self) -> None:
        low: int | None = None  # the lowest RSS since the last trim
        next_at = 0.0
        while not self._stop.wait(self.every_s):
            rss = rss_bytes()
            self.looks += 1
            if rss is None:
                continue
            low = rss if low is None else min(low, rss)
            if rss <= self.budget or rss - low < self.step or time.monotonic() < next_at:
                continue
            _trim()
            after = rss_bytes() or rss
            self.trims += 1
            self.returned += max(0, rss - after)
            low = after
            next_at = time.monotonic() + self.MIN_WAIT_S
