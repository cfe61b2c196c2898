"""Scenes of a run side by side: a bounded pipeline of scene workers (``run.workers``).

A scene goes generate → render → score → judge, and each stage waits on something else: a model
call on a provider, a render on Chromium (one browser pool per process), scoring on this
process's CPU, a judge on a provider again. `SceneScheduler` keeps several scenes in flight, each
on a thread of its own, so one scene scores while the next renders and a third waits for its
reply or its verdicts. `StageGates` holds a scene at a stage's entrance until what the stage
needs is free:

* **worker slots** (``run.workers`` of them): a scene takes one when it starts rendering or
  scoring and gives it back when it next waits on a provider (a repair call, its judges) or
  finishes. Only slot holders hold rendered clips and metric buffers, so slots bound memory as
  well as CPU; scenes waiting on a provider hold at most their decoded ground truth.
* **scoring memory**: what a scene holds while it scores grows with its clip (frames × width
  × height: its ground truth, clip, twin, still and paper clips, and the metrics' buffers), so
  the scenes scoring at once may hold at most `SCORE_PIXELS` clip pixels in all; a scene whose
  clip is larger scores alone. Two 3D scenes (75 frames of 512²) do not score side by side; a
  3D scene and 2D scenes (17 frames) do.
* **scenes in flight**: a scene decodes its ground truth as it starts and holds it while it
  waits; the scenes taken by the threads may hold at most `INFLIGHT_PIXELS` clip pixels in
  all (`SceneScheduler`), so 3D scenes wait fewer at a time than 2D scenes.
* **the render lane**: one render at a time (the process's browser pool prepares and restarts
  pages for one page at a time, and Chromium's GPU process runs WebGL serially anyway), and the
  first render of each scene in scene order (a turnstile), so the engine sees the programs in
  the order a single worker shows them.
* **the call lane**, with ``run.prefetch=0`` only: one model call at a time, first calls in
  scene order, so a cost cap stops exactly where a sequential run stops.

`SceneScheduler.results` hands scenes back in the order it was given them (a run gives them in
`work_order`: scenes too large to score side by side spread among the others); a scene that
finished early waits for the ones before it (at most ``window`` scenes are dispatched past the
oldest unfinished one).

Threads, not processes: rendering happens in Chromium's processes, and scoring spends its time
in torch, OpenCV, NumPy and the video codecs, which release the GIL; one process loads each
metric model once and keeps one per-frame cache. Outputs do not depend on the number of workers:
a scene's outputs are computed from its own inputs only, the metrics' per-frame cache returns
exactly what a fresh computation gives, and torch's intra-op threads are pinned for the run
(`pin_torch_threads`), since torch's reductions round differently with another thread count.
"""
# size: the scene scheduler and its stage gates share one lock discipline

from __future__ import annotations

import logging
import os
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence, TypeVar

from visphy_core.infra.errors import ConfigError
from visphy_core.infra.events import StageEvents
from visphy_core.infra.heap import BudgetTrim, limit_arenas

log = logging.getLogger("visphy.scheduler")

T = TypeVar("T")

AUTO = "auto"
#: What one worker may hold at its peak: a 3D scene's clips (75 frames of 512², ground truth,
#: render, S replayed, twin, frozen: about 300 MB) and the metrics' batch buffers.
WORKER_MEMORY_BYTES = 1536 * 2**20
#: What the run needs besides its workers: Python, torch and the metric models, one Chromium.
BASE_MEMORY_BYTES = 1536 * 2**20
#: torch's intra-op threads (`visphy_plugins.metrics._torch`), pinned by `pin_torch_threads`.
TORCH_THREADS_ENV = "VISPHY_TORCH_THREADS"
#: Clip pixels (frames × width × height, summed over the scenes in the ``score`` stage) that may be
#: scored at once: ``$VISPHY_SCORE_MPX`` million, else this. Measured (the default model and engine,
#: default suite, 2 workers): a 3D scene (75 frames of 512², 19.7 M pixels) holds about 0.35 GiB
#: while it scores (its ground truth, clip, twin, still and paper clips, 59 MB each, and the largest
#: metric's buffers, up to 0.2 GiB), a 2D scene (17 frames, 4.5 M) about a quarter of that; two 3D
#: scenes scoring at once were the run's peak. 32 M lets a 3D scene score beside 2D scenes, never
#: beside another 3D scene.
SCORE_PIXELS = 32_000_000
SCORE_PIXELS_ENV = "VISPHY_SCORE_MPX"
#: Clip pixels of the scenes in flight (taken by a worker thread, not finished), in all:
#: ``$VISPHY_INFLIGHT_MPX`` million, else this. A scene decodes its ground truth as it starts
#: and holds it while it waits for its reply, the render lane or a slot: measured with the
#: default model in the 3D part of the split, three scenes waited so, 56 MB each. 64 M keeps 3D
#: scenes to three in flight (the two slot holders and the next), 2D scenes to the threads.
INFLIGHT_PIXELS = 64_000_000
INFLIGHT_PIXELS_ENV = "VISPHY_INFLIGHT_MPX"
#: How often a waiting scene looks whether the run was cancelled (seconds).
POLL_S = 0.2


class SceneCancelled(BaseException):
    """Raised at a stage's entrance once the run is closing: the scene is abandoned (redone on
    resume). A `BaseException`, so no ``except Exception`` of a scene takes it for a fault."""


# --------------------------------------------------------------------------- sizing

def usable_cores() -> int:
    """The cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def available_memory() -> int | None:
    """``MemAvailable`` of /proc/meminfo in bytes (None where there is none)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def resolve_workers(value: object) -> int:
    """``run.workers`` as a number: an integer ≥ 1 as it is; ``auto`` the usable cores, at most
    as many as the available memory holds (`WORKER_MEMORY_BYTES` each over a base), at least 1."""
    text = str(value).strip().lower()
    if text == AUTO:
        cores = usable_cores()
        memory = available_memory()
        if memory is None:
            return cores
        return max(1, min(cores, (memory - BASE_MEMORY_BYTES) // WORKER_MEMORY_BYTES))
    try:
        number = int(text)
    except ValueError:
        number = 0
    if number < 1 or str(number) != text:
        raise ConfigError(f"run.workers={value} is not valid: must be auto or a whole number "
                          "≥ 1 (e.g. run.workers=2)")
    return number


def _pixels_setting(env: str, default: int) -> int:
    raw = os.environ.get(env, "").strip()
    if not raw:
        return default
    try:
        value = float(raw)
    except ValueError:
        value = -1.0
    if value < 0:
        raise ConfigError(f"${env}={raw} is not valid: a number of million clip pixels ≥ 0 "
                          "(0: no limit)")
    return int(value * 1_000_000)


def score_pixels() -> int:
    """`SCORE_PIXELS`, or ``$VISPHY_SCORE_MPX`` million when set (``0``: no limit)."""
    return _pixels_setting(SCORE_PIXELS_ENV, SCORE_PIXELS)


def inflight_pixels() -> int:
    """`INFLIGHT_PIXELS`, or ``$VISPHY_INFLIGHT_MPX`` million when set (``0``: no limit)."""
    return _pixels_setting(INFLIGHT_PIXELS_ENV, INFLIGHT_PIXELS)


def clip_pixels(item: object) -> int:
    """Frames × width × height of a scene's clip (its ``clip``: `visphy_core.infra.video.ClipInfo`);
    0 for an item without one."""
    clip = getattr(item, "clip", None)
    try:
        return max(0, int(clip.n_frames) * int(clip.width) * int(clip.height))
    except (AttributeError, TypeError, ValueError):
        return 0


def work_order(items: Sequence[T]) -> list[T]:
    """The order a run takes its scenes in: the large ones — clips too large for two to score
    side by side (`SCORE_PIXELS`), e.g. a benchmark's 3D scenes — spread evenly among the
    others, each group in its own order. Taken as listed, the 3D scenes (all at the end of the
    split) would score one at a time while the other worker waited; spread out, each scores
    beside 2D scenes and renders while they score. A list whose scenes are all large or all
    small keeps its order. Rows are still reported in scene order (`summary.json`,
    ``results.parquet``); ``results.jsonl`` is written in this order."""
    limit = score_pixels()
    if limit <= 0:
        return list(items)
    large = [x for x in items if 2 * clip_pixels(x) > limit]
    small = [x for x in items if 2 * clip_pixels(x) <= limit]
    if not large or not small:
        return list(items)
    out: list[T] = []
    placed = 0
    for i, item in enumerate(small):
        # the large scenes due before this small one: the k-th after (k + 1/2)·n/m small ones
        while placed < len(large) and (placed + 0.5) * len(small) / len(large) <= i:
            out.append(large[placed])
            placed += 1
        out.append(item)
    return out + large[placed:]


def pin_torch_threads() -> str:
    """Fix torch's intra-op threads for this process before any metric imports torch: the
    value of ``$VISPHY_TORCH_THREADS`` when set, else 1 (written to the environment).

    Why: torch splits reductions between its threads, so the last bits of FSIM, VSI or ST-LPIPS
    change with the thread count; a thread count that followed ``run.workers`` would make the
    scores depend on it. One thread per worker is also the fast setting where workers fill the
    cores. Returns the value in force.

    Also caps glibc's arenas (`visphy_core.infra.heap.limit_arenas`): it must happen before the
    run's threads start, as this does, and one arena lets a scene's thread reuse what the scenes
    before it freed on other threads."""
    limit_arenas()
    value = os.environ.setdefault(TORCH_THREADS_ENV, "1")
    import sys

    torch = sys.modules.get("torch")
    if torch is not None:  # imported already (another run in this process): set it now
        try:
            torch.set_num_threads(max(1, int(value)))
        except (ValueError, RuntimeError):
            pass
    return value


# --------------------------------------------------------------------------- gates

class Turnstile:
    """Lets scene ``i`` through after every scene before it passed (or never needed to)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._next = 0
        self._passed: set[int] = set()

    def wait(self, index: int, cancelled: threading.Event) -> None:
        with self._cond:
            while self._next < index:
                if cancelled.is_set():
                    raise SceneCancelled()
                self._cond.wait(POLL_S)

    def pass_(self, index: int) -> None:
        with self._cond:
            self._passed.add(index)
            while self._next in self._passed:
                self._passed.discard(self._next)
                self._next += 1
            self._cond.notify_all()


@dataclass
class _SceneState:
    """What the gates know of the scene a worker thread carries."""

    index: int
    scene_id: str
    holds_slot: bool = False
    generated: bool = False       # its first model call is over
    render_turn: bool = False     # it passed the render turnstile
    call_turn: bool = False       # it passed the call turnstile
    scoring: int = 0              # depth of "score" stages it is in
    pixels: int = 0               # its clip's pixels (`clip_pixels`): its scoring memory
    scores_now: bool = False      # it counts in the scoring memory


class StageGates(StageEvents):
    """Stage events that also gate: `stage` waits for the stage's resources (see the module
    docstring), then reports to ``inner`` (the run's progress). Outside a scene worker (no
    `bind`), stages pass through ungated."""

    def __init__(self, inner: StageEvents, workers: int, serial_calls: bool = False):
        self.inner = inner
        self.workers = workers
        self.cancelled = threading.Event()
        self._slots = threading.Semaphore(workers)
        self._render_lock = threading.Lock()
        self._render_turn = Turnstile()
        self._call_lock = threading.Lock() if serial_calls else None
        self._call_turn = Turnstile() if serial_calls else None
        self._local = threading.local()
        self.score_pixels = score_pixels()
        self._score_cond = threading.Condition()
        self._scoring: dict[int, int] = {}  # scene index -> its pixels, while it scores

    # -- events pass through
    def begin(self, stage: str, scene_id: str) -> None:
        self.inner.begin(stage, scene_id)

    def end(self, stage: str, scene_id: str) -> None:
        self.inner.end(stage, scene_id)

    def scene_finished(self, scene_id: str) -> None:
        self.inner.scene_finished(scene_id)

    # -- a worker's scene
    def bind(self, index: int, scene_id: str, pixels: int = 0) -> None:
        """The calling thread carries scene ``index`` (its position in the run) from now on;
        ``pixels``: its clip's (`clip_pixels`), what it may hold while it scores."""
        self._local.scene = _SceneState(index, scene_id, pixels=max(0, int(pixels)))

    def unbind(self) -> None:
        """The scene is over (finished, failed or cancelled): give back what it holds."""
        me: _SceneState | None = getattr(self._local, "scene", None)
        if me is None:
            return
        self._leave_scoring(me)
        self._release_slot(me)
        self._pass_render_turn(me)
        self._pass_call_turn(me)
        self._local.scene = None

    def scoring_now(self) -> dict[int, int]:
        """The scenes in the ``score`` stage now: index -> clip pixels."""
        with self._score_cond:
            return dict(self._scoring)

    def cancel(self) -> None:
        """Close the run: every scene is abandoned at its next stage entrance."""
        self.cancelled.set()

    def check(self) -> None:
        if self.cancelled.is_set():
            raise SceneCancelled()

    @contextmanager
    def render_lane(self, timeout_s: float) -> Iterator[bool]:
        """Hold the render lane (no scene renders meanwhile) for up to ``timeout_s`` of waiting;
        yields whether it was had. The run takes it before closing the engine."""
        got = self._render_lock.acquire(timeout=timeout_s)
        try:
            yield got
        finally:
            if got:
                self._render_lock.release()

    @contextmanager
    def stage(self, stage: str, scene_id: str) -> Iterator[None]:
        me: _SceneState | None = getattr(self._local, "scene", None)
        if me is None:
            with self.inner.stage(stage, scene_id):
                yield
            return
        self.check()
        held: list[threading.Lock] = []
        counted = False  # a "score" stage entered (its depth counted)
        try:
            if stage == "generate":
                self._enter_generate(me, held)
            elif stage == "render":
                if not me.scoring and not me.render_turn:
                    self._render_turn.wait(me.index, self.cancelled)
                self._take_slot(me)
                self._acquire(self._render_lock)
                held.append(self._render_lock)
                self.check()
            elif stage == "score":
                self._pass_render_turn(me)
                self._take_slot(me)
                if not me.scoring:
                    self._enter_scoring(me)
                me.scoring += 1
                counted = True
            elif stage == "judge":
                self._pass_render_turn(me)
                self._release_slot(me)
            self.inner.begin(stage, scene_id)
            yield
            self.inner.end(stage, scene_id)
        finally:
            for lock in reversed(held):
                lock.release()
            if stage == "generate" and not me.generated:
                me.generated = True
                self._pass_call_turn(me)
            elif stage == "render" and not me.scoring:
                self._pass_render_turn(me)
            elif stage == "score" and counted:
                me.scoring -= 1
                if not me.scoring:
                    self._leave_scoring(me)

    def _enter_generate(self, me: _SceneState, held: list) -> None:
        """A model call: no slot is kept while the provider answers; a repair call gives up the
        render turn; with serial calls, the call lane (first calls in scene order)."""
        if me.generated:
            self._pass_render_turn(me)
        self._release_slot(me)
        if self._call_lock is not None:
            if not me.generated:
                self._call_turn.wait(me.index, self.cancelled)
            self._acquire(self._call_lock)
            held.append(self._call_lock)

    def _enter_scoring(self, me: _SceneState) -> None:
        """Wait until the scenes scoring now leave room for this scene's clip (`SCORE_PIXELS`
        in all), or none scores; then count it in."""
        with self._score_cond:
            while True:
                if self.cancelled.is_set():
                    raise SceneCancelled()
                if not (self._scoring and self.score_pixels and
                        sum(self._scoring.values()) + me.pixels > self.score_pixels):
                    break
                self._score_cond.wait(POLL_S)
            self._scoring[me.index] = me.pixels
            me.scores_now = True

    def _leave_scoring(self, me: _SceneState) -> None:
        if me.scores_now:
            me.scores_now = False
            with self._score_cond:
                self._scoring.pop(me.index, None)
                self._score_cond.notify_all()

    def _acquire(self, lock) -> None:
        while not lock.acquire(timeout=POLL_S):
            self.check()

    def _take_slot(self, me: _SceneState) -> None:
        if not me.holds_slot:
            self._acquire(self._slots)
            me.holds_slot = True

    def _release_slot(self, me: _SceneState) -> None:
        if me.holds_slot:
            me.holds_slot = False
            self._slots.release()

    def _pass_render_turn(self, me: _SceneState) -> None:
        if not me.render_turn:
            me.render_turn = True
            self._render_turn.pass_(me.index)

    def _pass_call_turn(self, me: _SceneState) -> None:
        if self._call_turn is not None and not me.call_turn:
            me.call_turn = True
            self._call_turn.pass_(me.index)


# --------------------------------------------------------------------------- the scheduler

def scene_threads(workers: int) -> int:
    """Scenes in flight for ``workers`` slots: the slot holders, as many waiting on a provider
    (their reply, their judges), and one more ready to take the next free slot. One worker is
    one scene at a time, as a plain loop would go (the prefetch still calls ahead)."""
    return 1 if workers == 1 else 2 * workers + 1


class SceneScheduler:
    """Runs ``process(item)`` for every item on `scene_threads` worker threads (daemons: a run
    that closes never waits for an abandoned scene) and yields the outcomes in item order.

    ``on_dispatch(i)`` runs when item ``i`` is taken (the run's prefetch). An outcome is what
    ``process`` returned, or the exception it raised (a `SceneCancelled` scene has none).

    A thread takes the next scene only while the scenes in flight leave room for its clip
    (`INFLIGHT_PIXELS`), or none is in flight. While the scenes run, ``trim``
    (`visphy_core.infra.heap.BudgetTrim`) hands the allocator's free
    pages back whenever the process is above its memory budget (the run also trims after each
    scene); it stops with `results` or `cancel`.
    """

    def __init__(self, items: Sequence[T], key: Callable[[T], str], process: Callable[[T], object],
                 gates: StageGates, window: int | None = None,
                 on_dispatch: Callable[[int], None] | None = None):
        self.items = list(items)
        self.key = key
        self.process = process
        self.gates = gates
        self.threads = min(scene_threads(gates.workers), max(1, len(self.items)))
        self.window = max(window or 0, 4 * gates.workers + 4, self.threads)
        self.inflight_pixels = inflight_pixels()
        self._pixels = [clip_pixels(item) for item in self.items]
        self._inflight: dict[int, int] = {}  # scene index -> its clip pixels, while in flight
        self.on_dispatch = on_dispatch
        self._cond = threading.Condition()
        self._next_dispatch = 0
        self._next_yield = 0
        self._outcomes: dict[int, object] = {}
        self._draining = False
        self._alive = 0
        self._started = False
        #: trims the allocator's free pages while the process is above its memory budget
        self.trim = BudgetTrim()

    def _worker(self) -> None:
        try:
            while True:
                with self._cond:
                    while (not self._draining and self._next_dispatch < len(self.items)
                           and (self._next_dispatch >= self._next_yield + self.window
                                or self._no_room(self._next_dispatch))):
                        self._cond.wait(POLL_S)
                    if self._draining or self._next_dispatch >= len(self.items):
                        return
                    index = self._next_dispatch
                    self._next_dispatch += 1
                    self._inflight[index] = self._pixels[index]
                item = self.items[index]
                if self.on_dispatch is not None:
                    try:
                        self.on_dispatch(index)
                    except Exception as exc:  # noqa: BLE001 - a hint ahead, never the scene
                        log.warning("on_dispatch(%d) failed: %s: %s", index,
                                    type(exc).__name__, exc)
                self.gates.bind(index, self.key(item), clip_pixels(item))
                try:
                    outcome: object = self.process(item)
                except SceneCancelled:
                    return
                except BaseException as exc:  # noqa: BLE001 - handed to the run's thread
                    outcome = exc
                finally:
                    self.gates.unbind()
                    with self._cond:
                        self._inflight.pop(index, None)
                        self._cond.notify_all()
                with self._cond:
                    self._outcomes[index] = outcome
                    self._cond.notify_all()
        finally:
            with self._cond:
                self._alive -= 1
                self._cond.notify_all()

    def _no_room(self, index: int) -> bool:
        """Whether scene ``index`` must wait for the scenes in flight (`INFLIGHT_PIXELS`)."""
        return bool(self.inflight_pixels and self._inflight and
                    sum(self._inflight.values()) + self._pixels[index] > self.inflight_pixels)

    def inflight_now(self) -> dict[int, int]:
        """The scenes in flight now: index -> clip pixels."""
        with self._cond:
            return dict(self._inflight)

    def _start(self) -> None:
        self._started = True
        self.trim.start()
        for n in range(self.threads):
            with self._cond:
                self._alive += 1
            threading.Thread(target=self._worker, name=f"visphy-scene-{n}", daemon=True).start()

    def results(self) -> Iterator[tuple[T, object]]:
        """(item, outcome) in item order, each as soon as it and every item before it are done.
        After `drain`, only the items already taken come (then the iteration ends)."""
        if not self._started:
            self._start()
        try:
            while True:
                with self._cond:
                    while self._next_yield not in self._outcomes:
                        if self.gates.cancelled.is_set():
                            return  # the scenes in flight are abandoned
                        if self._next_yield >= (self._next_dispatch if self._draining
                                                else len(self.items)):
                            return
                        if self._alive == 0:
                            raise RuntimeError(f"scene {self.key(self.items[self._next_yield])}"
                                               " was taken by a worker that is gone")
                        self._cond.wait(POLL_S)
                    index = self._next_yield
                    outcome = self._outcomes.pop(index)
                    self._next_yield += 1
                    self._cond.notify_all()
                yield self.items[index], outcome
        finally:
            self.trim.stop()

    def join(self, timeout_s: float) -> int:
        """Wait up to ``timeout_s`` for the worker threads to end (after `cancel`, each ends at
        its scene's next stage entrance); returns how many are still running. A process must
        not exit under a thread that is inside torch or a codec: its runtime aborts."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._alive and time.monotonic() < deadline:
                self._cond.wait(min(POLL_S, max(0.0, deadline - time.monotonic())))
            return self._alive

    def drain(self) -> None:
        """Take no further item; the ones taken finish and still come out of `results`."""
        with self._cond:
            self._draining = True
            self._cond.notify_all()

    def cancel(self) -> None:
        """Take no further item and abandon the ones in flight (at their next stage)."""
        self.drain()
        self.gates.cancel()
        self.trim.stop()
