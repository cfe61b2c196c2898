"""A run's memory stays bounded over its scenes (`visphy_core.infra.heap`,
`visphy_core.execute.scheduler`, `visphy_core.sandbox.browser`).

What grew with the number of scenes: every rendered clip's frames, held by the finished page's
handlers in reference cycles that only CPython's cycle collector frees (and its full
collections came rarely); glibc's per-thread arenas; freed pages kept resident. What set the
high-water mark: two 3D scenes scoring at once, Chromium's spare renderer, the Node.js driver's
young generation. Each test below fails without the fix it names.
"""

from __future__ import annotations

import gc
import os
import subprocess
import sys
import textwrap
import threading
import time
import weakref
from dataclasses import dataclass

import numpy as np
import pytest

from conftest import REPO

glibc_only = [pytest.mark.skip_ok(reason="another platform, not a missing dependency"),
              pytest.mark.skipif(not sys.platform.startswith("linux"),
                                 reason="glibc's allocator")]


# ------------------------------------------------------------------ captures leave no frames behind

def test_a_detached_capture_takes_the_frames_and_leaves_none_behind():
    from visphy_core.sandbox.browser import PageCapture

    frames = [np.zeros((4, 4, 3), np.uint8) for _ in range(3)]
    cap = PageCapture(frames=frames, errors=["e"], console=["c"], timed_out=True,
                      timings={"load": 0.1}, raw_frames=3, isolation="x")
    out = cap.detached()
    assert out is not cap
    assert out.frames is frames and out.errors == ["e"] and out.console == ["c"]
    assert out.timed_out and out.raw_frames == 3 and out.timings == {"load": 0.1}
    assert out.isolation == "x"
    # what the page's handlers still reference holds nothing large
    assert cap.frames == [] and cap.errors == [] and cap.timings == {}


COUNTER_PAGE = """<html><body><canvas id="c" width="96" height="96"></canvas><script>
const ctx = document.getElementById('c').getContext('2d');
function draw() {
  ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, 96, 96);
  ctx.fillStyle = '#f34f46'; ctx.fillRect(Math.round(performance.now() / 20) % 80, 40, 10, 10);
  requestAnimationFrame(draw);
}
requestAnimationFrame(draw);
console.log('ready');
</script></body></html>"""


@pytest.mark.browser
def test_a_rendered_clip_is_freed_without_the_cycle_collector():
    """The frames a page captured go when the caller drops them, not at the next full garbage
    collection: the page's listeners, router and coroutine frame sit in reference cycles."""
    from visphy_core.sandbox.browser import BrowserPool

    with BrowserPool() as pool:
        pool.render_page(COUNTER_PAGE, {}, [0.0, 100.0], width=96, height=96, timeout_s=30)
        gc.collect()
        gc.disable()
        try:
            refs = []
            for _ in range(3):
                cap = pool.render_page(COUNTER_PAGE, {}, [0.0, 100.0, 200.0], width=96,
                                       height=96, timeout_s=30)
                assert len(cap.frames) == 3, (cap.errors, cap.infra_error)
                refs += [weakref.ref(f) for f in cap.frames]
                del cap
            alive = sum(r() is not None for r in refs)
        finally:
            gc.enable()
    assert alive == 0, f"{alive} of {len(refs)} frames still held after the captures were dropped"


# ------------------------------------------------------------------ the per-scene collection

def _cycle_with_array(nbytes: int) -> weakref.ref:
    class Node:
        pass

    a, b = Node(), Node()
    a.other, b.other = b, a
    a.pixels = np.ones(nbytes, np.uint8)
    return weakref.ref(a.pixels)


def test_release_free_memory_frees_what_only_cycles_hold(monkeypatch):
    from visphy_core.infra import heap
    gc.collect()
    gc.disable()
    try:
        monkeypatch.setenv(heap.GC_ENV, "0")
        kept = _cycle_with_array(2**20)
        heap.release_free_memory()
        assert kept() is not None  # turned off: the cycle waits for CPython's own collection
        monkeypatch.delenv(heap.GC_ENV)
        freed = _cycle_with_array(2**20)
        heap.release_free_memory()
        assert freed() is None and kept() is None
    finally:
        gc.enable()


# ------------------------------------------------------------------ glibc: arenas and the budget

ARENAS_SCRIPT = textwrap.dedent("""
    import ctypes, io, os, re, sys, tempfile, threading
    import numpy as np
    sys.path.insert(0, {repo!r})
    from visphy_core.infra.heap import limit_arenas
    print("limit", limit_arenas())
    go = threading.Barrier(6)
    def work():
        go.wait()  # all six allocate at once: glibc would give each an arena of its own
        blocks = [np.ones(64 * 1024, np.uint8) for _ in range(200)]
        go.wait()
    threads = [threading.Thread(target=work) for _ in range(6)]
    for t in threads: t.start()
    for t in threads: t.join()
    libc = ctypes.CDLL("libc.so.6")
    libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
    libc.fopen.restype = ctypes.c_void_p
    path = tempfile.mktemp()
    fh = libc.fopen(path.encode(), b"w")
    libc.malloc_info(0, fh)
    libc.fclose(ctypes.c_void_p(fh))
    print("arenas", len(re.findall(r"<heap nr=", open(path).read())))
""")


def _arenas(env: dict) -> tuple[str, int]:
    env = {k: v for k, v in {**os.environ, **env}.items() if k != "MALLOC_ARENA_MAX"}
    out = subprocess.run([sys.executable, "-c", ARENAS_SCRIPT.format(repo=str(REPO))],
                         capture_output=True, text=True, check=True, env=env).stdout.split()
    return out[1], int(out[3])


@pytest.mark.parametrize("mark", glibc_only)
def test_one_arena_serves_every_thread(mark):
    from visphy_core.infra.heap import ARENAS_ENV

    assert _arenas({ARENAS_ENV: ""}) == ("1", 1)
    limit, arenas = _arenas({ARENAS_ENV: "0"})  # glibc's default: an arena per thread
    assert limit == "None" and arenas > 1


def test_the_run_caps_the_arenas_before_its_threads_start(monkeypatch):
    from visphy_core.execute import scheduler
    from visphy_core.infra import heap
    calls = []
    monkeypatch.setattr(scheduler, "limit_arenas", lambda: calls.append(1))
    scheduler.pin_torch_threads()
    assert calls == [1]
    monkeypatch.setenv(heap.ARENAS_ENV, "many")
    with pytest.raises(ValueError, match=heap.ARENAS_ENV):
        heap.limit_arenas()


BUDGET_SCRIPT = textwrap.dedent("""
    import sys, threading, time
    import numpy as np
    sys.path.insert(0, {repo!r})
    from visphy_core.infra.heap import BudgetTrim, rss_bytes
    keep = []
    def scene():  # on a thread, as a run's scenes are
        big = np.ones(16 * 2**20, np.uint8); del big  # glibc's mmap threshold rises to 16 MiB
        blocks = [np.ones(2**20, np.uint8) for _ in range(300)]  # served by the arena
        keep.append(blocks[-1])  # pins the arena's top: free() alone cannot shrink it
    t = threading.Thread(target=scene); t.start(); t.join()
    freed = rss_bytes()
    trim = BudgetTrim(budget=freed - 200 * 2**20, every_s=0.05, step=64 * 2**20)
    assert trim.start()
    deadline = time.monotonic() + 20
    while trim.looks < 3 and time.monotonic() < deadline:
        time.sleep(0.05)  # it has seen the RSS: above the budget, but no growth yet
    quiet = trim.trims
    more = np.ones(100 * 2**20, np.uint8)  # the next scene's buffer: the RSS grows again
    deadline = time.monotonic() + 20
    while trim.trims == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    trim.stop()
    print(freed // 2**20, rss_bytes() // 2**20, quiet, trim.trims, trim.returned // 2**20,
          int(trim.running))
""")


@pytest.mark.parametrize("mark", glibc_only)
def test_pages_go_back_once_the_process_grows_above_its_budget(mark):
    proc = subprocess.run([sys.executable, "-c", BUDGET_SCRIPT.format(repo=str(REPO))],
                          capture_output=True, text=True, check=True,
                          env={**os.environ, "VISPHY_MALLOC_TRIM": "1"})
    freed, after, quiet, trims, returned, running = map(int, proc.stdout.split())
    assert freed > 300 and running == 0
    assert quiet == 0 and trims >= 1  # no trim before the RSS grew by a step
    # the 300 MiB freed earlier went back; the 100 MiB buffer in use stays
    assert after < freed - 150 and returned > 150


def test_no_budget_or_no_trim_starts_nothing(monkeypatch):
    from visphy_core.infra import heap
    assert heap.BudgetTrim(budget=0).start() is False
    monkeypatch.setenv(heap.TRIM_ENV, "0")
    assert heap.BudgetTrim(budget=2**20).start() is False
    monkeypatch.delenv(heap.TRIM_ENV)
    monkeypatch.setenv(heap.BUDGET_ENV, "512")
    assert heap.budget_bytes() == 512 * 2**20
    monkeypatch.setenv(heap.BUDGET_ENV, "lots")
    with pytest.raises(ValueError, match=heap.BUDGET_ENV):
        heap.budget_bytes()


# ------------------------------------------------------------------ the scoring memory gate

@dataclass(frozen=True)
class _Clip:
    n_frames: int
    width: int = 512
    height: int = 512


@dataclass(frozen=True)
class _Scene:
    scene_id: str
    clip: _Clip


def _run_scenes(scenes, workers: int, budget_mpx: str, monkeypatch) -> list[int]:
    """Each scene renders, then scores for a while; returns the clip pixels scoring at once,
    as seen from inside every score stage."""
    from visphy_core.execute.scheduler import SCORE_PIXELS_ENV, SceneScheduler, StageGates
    from visphy_core.infra.events import StageEvents

    monkeypatch.setenv(SCORE_PIXELS_ENV, budget_mpx)
    gates = StageGates(StageEvents(), workers)
    seen: list[int] = []

    def process(scene):
        with gates.stage("generate", scene.scene_id):
            pass
        with gates.stage("render", scene.scene_id):
            pass
        with gates.stage("score", scene.scene_id):
            for _ in range(4):
                seen.append(sum(gates.scoring_now().values()))
                time.sleep(0.05)
        return scene.scene_id

    sched = SceneScheduler(scenes, key=lambda s: s.scene_id, process=process, gates=gates)
    done = [outcome for _, outcome in sched.results()]
    assert done == [s.scene_id for s in scenes]
    assert not sched.trim.running
    return seen


def test_two_3d_scenes_never_score_at_once(monkeypatch):
    scenes = [_Scene(f"3d-{i}", _Clip(75)) for i in range(4)]
    seen = _run_scenes(scenes, workers=2, budget_mpx="32", monkeypatch=monkeypatch)
    assert max(seen) == 75 * 512 * 512
    # the limit is what holds them apart: without it the same scenes overlap
    seen = _run_scenes(scenes, workers=2, budget_mpx="0", monkeypatch=monkeypatch)
    assert max(seen) == 2 * 75 * 512 * 512


def test_2d_scenes_score_side_by_side_and_beside_a_3d_scene(monkeypatch):
    from visphy_core.execute.scheduler import SCORE_PIXELS

    scenes = [_Scene("3d", _Clip(75))] + [_Scene(f"2d-{i}", _Clip(17)) for i in range(5)]
    seen = _run_scenes(scenes, workers=3, budget_mpx="32", monkeypatch=monkeypatch)
    assert max(seen) <= SCORE_PIXELS


def test_a_scene_waiting_for_scoring_memory_is_abandoned_on_cancel(monkeypatch):
    from visphy_core.execute.scheduler import SCORE_PIXELS_ENV, SceneCancelled, StageGates
    from visphy_core.infra.events import StageEvents

    monkeypatch.setenv(SCORE_PIXELS_ENV, "32")
    gates = StageGates(StageEvents(), 2)
    inside, outcome = threading.Event(), {}

    def first():
        gates.bind(0, "a", 75 * 512 * 512)
        with gates.stage("score", "a"):
            inside.set()
            while not gates.cancelled.is_set():
                time.sleep(0.01)
        gates.unbind()

    def second():
        gates.bind(1, "b", 75 * 512 * 512)
        inside.wait()
        try:
            with gates.stage("score", "b"):
                outcome["b"] = "scored"
        except SceneCancelled:
            outcome["b"] = "cancelled"
        gates.unbind()

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for t in threads:
        t.start()
    inside.wait()
    time.sleep(0.3)  # b is now waiting at the entrance (or about to); either way a stays
    assert "b" not in outcome and gates.scoring_now() == {0: 75 * 512 * 512}
    gates.cancel()
    for t in threads:
        t.join(10)
    assert outcome == {"b": "cancelled"} and gates.scoring_now() == {}


def test_3d_scenes_in_flight_are_fewer_than_the_threads(monkeypatch):
    """Scenes hold their decoded ground truth from their start: with 3D clips, no more of them
    are taken than `INFLIGHT_PIXELS` allows, though threads are free (and without the limit
    they are)."""
    from visphy_core.execute.scheduler import INFLIGHT_PIXELS_ENV, SceneScheduler, StageGates
    from visphy_core.infra.events import StageEvents

    def run(limit: str) -> tuple[int, int]:
        monkeypatch.setenv(INFLIGHT_PIXELS_ENV, limit)
        gates = StageGates(StageEvents(), 2)
        seen: list[dict] = []
        box: list[SceneScheduler] = []

        def process(scene):
            for _ in range(4):
                seen.append(box[0].inflight_now())
                time.sleep(0.05)
            return scene.scene_id

        box.append(SceneScheduler([_Scene(f"3d-{i}", _Clip(75)) for i in range(8)],
                                  key=lambda s: s.scene_id, process=process, gates=gates))
        assert [o for _, o in box[0].results()] == [f"3d-{i}" for i in range(8)]
        assert box[0].threads == 5 and box[0].inflight_now() == {}
        return max(len(s) for s in seen), max(sum(s.values()) for s in seen)

    most, pixels = run("64")
    assert most == 3 and pixels <= 64_000_000
    assert run("0")[0] == 5


def test_clip_pixels_and_the_limit_setting(monkeypatch):
    from visphy_core.api.errors import ConfigError
    from visphy_core.execute.scheduler import (
        INFLIGHT_PIXELS_ENV,
        SCORE_PIXELS_ENV,
        clip_pixels,
        inflight_pixels,
        score_pixels,
    )

    assert clip_pixels(_Scene("s", _Clip(17))) == 17 * 512 * 512
    assert clip_pixels(object()) == 0
    monkeypatch.setenv(SCORE_PIXELS_ENV, "2.5")
    assert score_pixels() == 2_500_000
    monkeypatch.setenv(SCORE_PIXELS_ENV, "-1")
    with pytest.raises(ConfigError, match=SCORE_PIXELS_ENV):
        score_pixels()
    monkeypatch.setenv(INFLIGHT_PIXELS_ENV, "many")
    with pytest.raises(ConfigError, match=INFLIGHT_PIXELS_ENV):
        inflight_pixels()


# ------------------------------------------------------------------ Chromium and its driver

def test_the_launcher_merges_every_feature_list_into_one():
    from visphy_core.sandbox.chromium import MERGE_FEATURES_SH

    script = MERGE_FEATURES_SH + 'printf "%s\\n" "$@"\n'
    out = subprocess.run(["sh", "-c", script, "sh", "--a", "--disable-features=A,B",
                          "--enable-features=E", "--b c", "--disable-features=C"],
                         capture_output=True, text=True, check=True).stdout.splitlines()
    assert out == ["--a", "--b c", "--disable-features=A,B,C", "--enable-features=E"]


@pytest.mark.browser
def test_chromium_runs_with_playwrights_features_and_without_a_spare_renderer():
    from visphy_core.sandbox.browser import BrowserPool
    from visphy_core.sandbox.chromium import _proc_type

    with BrowserPool() as pool:
        cap = pool.render_page(COUNTER_PAGE, {}, [0.0], width=96, height=96, timeout_s=30)
        assert len(cap.frames) == 1, (cap.errors, cap.infra_error)
        proc = pool._browsers[0]
        browsers = [pid for pid in proc.processes(("browser",))
                    if _proc_type(pid) == "browser" and b"chromium" in
                    open(f"/proc/{pid}/cmdline", "rb").read().split(b"\0")[0]]
        args = [a.decode() for a in open(f"/proc/{browsers[0]}/cmdline", "rb").read()
                .split(b"\0")]
    disabled = [a for a in args if a.startswith("--disable-features=")]
    assert len(disabled) == 1
    features = disabled[0].split("=", 1)[1].split(",")
    assert "SpareRendererForSitePerProcess" in features
    assert len(features) > 1  # Playwright's own list is still there


def test_the_driver_starts_with_a_small_young_generation(monkeypatch):
    from visphy_core.sandbox import browser

    monkeypatch.delenv("NODE_OPTIONS", raising=False)
    with browser._driver_node_options():
        assert os.environ["NODE_OPTIONS"] == browser.DRIVER_NODE_OPTIONS
    assert "NODE_OPTIONS" not in os.environ
    monkeypatch.setenv("NODE_OPTIONS", "--enable-source-maps")
    with browser._driver_node_options():
        assert os.environ["NODE_OPTIONS"] == \
            f"--enable-source-maps {browser.DRIVER_NODE_OPTIONS}"
    assert os.environ["NODE_OPTIONS"] == "--enable-source-maps"
    monkeypatch.setenv("NODE_OPTIONS", "--max-semi-space-size=8")
    with browser._driver_node_options():  # the user's own value stands
        assert os.environ["NODE_OPTIONS"] == "--max-semi-space-size=8"
