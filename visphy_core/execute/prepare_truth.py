"""A dataset's ground-truth artefacts computed ahead of scoring
(`visphy_core.scoring.ground_truth`): for each scene, the headline components' floors (what the
still clip scores) and, with ``metrics.variance_norm=true``, the twin rendered by the engine's
reference program and every frame/sequence metric's floor and ceiling, into the ground-truth
store (``paths.ground_truth_dir``).

Two callers: ``python -m visphy_core ground-truth [overrides]`` (`prepare`: a dataset's scenes
ahead of any run), and a run itself (`fill_store`, its ``ground truth`` stage: the scenes it is
about to score, before the first one is scored, so a first run's extra cost is a stage of its
own with its time shown, and a later run finds everything stored). The overrides are a run's
(``dataset=``, ``engine=``, ``metrics=``, ``paths.*``): the artefacts are the ones a run with
the same overrides reads. Scenes already done are skipped — a scene whose every anchor was
stored gets a completion mark (`complete_key`), so a later run checks it without decoding the
scene's clip — so it resumes after an interruption; a scene whose twin cannot be made is
reported (the run's normalisation then says why for that scene), never fatal.

Two scenes are in flight at a time (``workers``): one renders its twin (one render at a
time: the browser pool renders one page at a time) while the other scores.
"""

from __future__ import annotations

import json
import resource
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from visphy_core.infra.events import StageEvents

if TYPE_CHECKING:
    from visphy_core.api.engine import Engine
    from visphy_core.api.metrics import Metric
    from visphy_core.api.scene import Scene
    from visphy_core.infra.cache import Cache

#: what a completion mark's key is made of (bumped when that changes)
MARK_VERSION = "ground-truth-scene/1"


class _RenderLane(StageEvents):
    """One render at a time across the threads; other stages run side by side."""

    def __init__(self) -> None:
        self._lock = threading.Lock()

    @contextmanager
    def stage(self, stage: str, scene_id: str) -> Iterator[None]:
        if stage != "render":
            yield
            return
        with self._lock:
            yield


@dataclass
class Filled:
    """What `fill_store` did: scenes whose anchors are all there now (``done``), of them those
    found complete (``reused``), values computed now, scenes it could not complete and why,
    wall seconds and CPU seconds of this process (Chromium's rendering not included)."""

    total: int
    done: int = 0
    reused: int = 0
    computed: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    wall_s: float = 0.0
    cpu_s: float = 0.0

    def as_dict(self) -> dict:
        return {"scenes": self.total, "done": self.done, "reused": self.reused,
                "computed_now": self.done - self.reused, "values_computed": self.computed,
                "failed": [{"scene_id": s, "why": w} for s, w in self.failed],
                "wall_s": round(self.wall_s, 2), "cpu_s": round(self.cpu_s, 2)}

    def line(self) -> str:
        """One line for the console: what was computed, its cost, what was already there."""
        from visphy_core.infra.progress import duration

        fresh = self.done - self.reused
        parts = []
        if fresh:
            parts.append(f"{fresh} computed now in {duration(self.wall_s)} "
                         f"({self.cpu_s:.0f} CPU-s here; stored, later runs reuse it)")
        if self.reused:
            parts.append(f"{self.reused} already stored")
        if self.failed:
            parts.append(f"{len(self.failed)} without (their normalisation says why)")
        return (f"ground truth of {self.total} scene{'s' if self.total != 1 else ''}: "
                + ("; ".join(parts) or "none needed"))


def complete_key(scene: "Scene", engine: "Engine", metrics: list["Metric"], contract,
                 ceiling: bool) -> str | None:
    """The key of the mark saying every anchor of ``metrics`` on ``scene`` is stored: the scene's
    files (clip, key frames, spec, trajectory) by content, the engine, the contract, each
    metric's identity, the codec. None when a file cannot be read (no mark: look it up)."""
    import av

    from visphy_core.infra.cache import content_key, file_digest
    from visphy_core.infra.video import H264_OPTIONS
    from visphy_core.scoring.ground_truth import VERSION

    paths = [scene.video_path, *(scene.keyframe_paths[k] for k in sorted(scene.keyframe_paths)),
             scene.spec_path, scene.trajectory_path]
    try:
        digests = [file_digest(Path(p)) if p is not None else None for p in paths]
    except OSError:
        return None
    return content_key(MARK_VERSION, VERSION, digests, engine.cache_identity(), contract.key(),
                       sorted((m.name, m.version, m.identity()) for m in metrics), ceiling,
                       H264_OPTIONS, av.__version__)


def fill_store(scenes: list["Scene"], engine: "Engine", metrics: list["Metric"],
               cache: "Cache", store: "Cache | None", *, ceiling: bool, timeout_s: float,
               seed: int, workers: int = 2, progress: bool = True,
               description: str = "ground truth") -> Filled:
    """Every frame/sequence metric's floor (and with ``ceiling`` its ceiling: the twin's
    render and scores) on each scene, read or computed into ``store`` (the run cache when the
    store is not writable). A scene that cannot be loaded is left to its run; one whose
    anchors cannot be made is in ``failed``. A machine fault (a full disk) is raised."""
    from visphy_core.api.engine import RenderContract
    from visphy_core.api.metrics import SCENE
    from visphy_core.execute.pipeline import EngineReferenceClips
    from visphy_core.infra.errors import host_fault
    from visphy_core.infra.progress import track
    from visphy_core.scoring.ground_truth import scene_anchors, writable
    from visphy_core.scoring.reference_clips import ReferenceClipUnavailable

    frame = [m for m in metrics if m.kind != SCENE and not m.unavailable_reason()]
    # the marks live in the store only: the run cache may be off or swept
    marks = store if writable(store) else None
    lane = _RenderLane()
    out = Filled(total=len(scenes))
    lock = threading.Lock()
    start, cpu0 = time.perf_counter(), _cpu_s()

    def one(scene: "Scene") -> None:
        if scene.load_error or not frame:
            return
        contract = RenderContract.for_scene(scene, timeout_s=timeout_s, seed=seed)
        key = complete_key(scene, engine, frame, contract, ceiling) if marks else None
        if key is not None and marks.get("ground-truth-scene", key) is not None:
            with lock:
                out.done += 1
                out.reused += 1
            return
        clips = EngineReferenceClips(engine, cache, lane, None, store)
        try:
            found = scene_anchors(scene, scene.reference_frames(), frame, clips, contract,
                                  cache, store, None, ceiling=ceiling)
        except (ReferenceClipUnavailable, ValueError, OSError) as exc:
            if isinstance(exc, OSError) and host_fault(exc) is not None:
                raise
            with lock:
                out.failed.append((scene.scene_id, " ".join(str(exc).split())[:300]))
            return
        complete = not found.why_floor and (not ceiling or not found.why_ceiling)
        if key is not None and complete:
            marks.put("ground-truth-scene", key,
                      {"mark.json": json.dumps({"scene_id": scene.scene_id,
                                                "values_computed": found.computed})})
        with lock:
            out.done += 1
            out.computed += found.computed
            if not found.computed:
                out.reused += 1

    pool = ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="visphy-gt")
    try:
        for _ in track(pool.map(one, scenes), len(scenes), description, progress):
            pass
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)  # an interrupt: no scene starts now
        raise
    pool.shutdown(wait=True)
    out.wall_s, out.cpu_s = time.perf_counter() - start, _cpu_s() - cpu0
    return out


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def prepare(overrides: list[str], workers: int = 2, progress: bool = True) -> int:
    from visphy_core.api.registry import get_registry
    from visphy_core.config.check import compose
    from visphy_core.execute.datasets import load_dataset
    from visphy_core.execute.scheduler import pin_torch_threads
    from visphy_core.infra.cache import Cache
    from visphy_core.infra.errors import UserError
    from visphy_core.scoring.ground_truth import open_store, store_path, writable
    from visphy_core.scoring.headline import Headline
    from visphy_core.scoring.score import select_metrics

    registry = get_registry()  # plugins store their structured configs before Hydra composes
    cfg = compose(list(overrides))
    pin_torch_threads()
    data_dir = Path(str(cfg.paths.data_dir)).resolve()
    store = open_store(store_path(cfg, data_dir))
    if not writable(store):
        raise UserError(f"ground-truth: the store {store_path(cfg, data_dir)} is not set or not "
                        "writable (paths.ground_truth_dir)")
    cache = Cache(Path(str(cfg.paths.cache_dir)).resolve(), enabled=bool(cfg.run.cache))
    scenes = load_dataset(cfg.dataset, data_dir, progress=progress)
    engine = registry.get("engines", cfg.engine.name)(cfg.engine)
    metrics = select_metrics(registry, cfg.metrics)
    # what a run with the same overrides reads (`execute.run._ground_truth_stage`): every
    # metric's floor and the twin's ceiling with normalisation on, else the headline's floors
    norm = bool(cfg.metrics.get("variance_norm", False))
    if not norm:
        headline = Headline.for_run(cfg.metrics, metrics)
        metrics = headline.metrics_of(metrics) if headline is not None else []
    if not metrics:
        engine.close()
        print("ground truth: nothing to compute (no headline component among the metrics and "
              "metrics.variance_norm=false)")
        return 0
    try:
        filled = fill_store(scenes, engine, metrics, cache, store, ceiling=norm,
                            timeout_s=float(cfg.engine.timeout_s), seed=int(cfg.run.seed),
                            workers=workers, progress=progress)
    finally:
        engine.close()  # the browser pool and its processes: no survivors
    for scene in scenes:
        if scene.load_error:
            print(f"{scene.scene_id}: not loaded: {scene.load_error}", file=sys.stderr)
    for scene_id, why in filled.failed:
        print(f"{scene_id}: no ground-truth artefacts: {why}", file=sys.stderr)
    frame = sum(m.kind != "scene" for m in metrics)
    print(f"ground truth of {filled.done}/{len(scenes)} scene(s) for {engine.cache_identity()} "
          f"× {frame} frame/sequence metric(s) in {store.root}: {filled.computed} value(s) "
          f"computed, the rest already there ({filled.wall_s:.1f} s)")
    return 0
