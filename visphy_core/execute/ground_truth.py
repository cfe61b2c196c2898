"""A dataset's ground-truth artefacts computed ahead of any run (``python -m visphy_core
ground-truth [overrides]``; `visphy_core.scoring.ground_truth`): for each selected scene, the twin
rendered by the engine's reference program and every frame/sequence metric's floor and ceiling,
into the ground-truth store (``paths.ground_truth_dir``). The overrides are a run's
(``dataset=``, ``engine=``, ``metrics=``, ``paths.*``): the artefacts are the ones a run with
the same overrides reads. Scenes already done are skipped (their entries are found), so it
resumes after an interruption, and a scene whose twin cannot be made is reported, never fatal.

Two scenes are in flight at a time (``--workers``): one renders its twin (one render at a
time: the browser pool renders one page at a time) while the other scores.
"""

from __future__ import annotations

import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from visphy_core.infra.events import StageEvents


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


def prepare(overrides: list[str], workers: int = 2, progress: bool = True) -> int:
    from visphy_core.infra.progress import track

    from visphy_core.api.engine import RenderContract
    from visphy_core.api.registry import get_registry
    from visphy_core.config.check import compose
    from visphy_core.execute.datasets import load_dataset
    from visphy_core.execute.pipeline import EngineReferenceClips
    from visphy_core.execute.scheduler import pin_torch_threads
    from visphy_core.infra.cache import Cache
    from visphy_core.infra.errors import UserError
    from visphy_core.scoring.ground_truth import open_store, scene_anchors, store_path, writable
    from visphy_core.scoring.reference_clips import ReferenceClipUnavailable
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
    lane = _RenderLane()
    start = time.perf_counter()
    done, failed, computed = 0, [], 0
    lock = threading.Lock()

    def one(scene) -> None:
        nonlocal done, computed
        if scene.load_error:
            with lock:
                failed.append((scene.scene_id, scene.load_error))
            return
        clips = EngineReferenceClips(engine, cache, lane, None, store)
        contract = RenderContract.for_scene(scene, timeout_s=float(cfg.engine.timeout_s),
                                            seed=int(cfg.run.seed))
        try:
            reference = scene.reference_frames()
            found = scene_anchors(scene, reference, metrics, clips, contract, cache, store,
                                  None)
        except (ReferenceClipUnavailable, ValueError, OSError) as exc:
            with lock:
                failed.append((scene.scene_id, " ".join(str(exc).split())[:300]))
            return
        with lock:
            done += 1
            computed += found.computed

    try:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            for _ in track(pool.map(one, scenes), len(scenes), "ground truth", progress):
                pass
    finally:
        engine.close()  # the browser pool and its processes: no survivors
    for scene_id, why in failed:
        print(f"{scene_id}: no ground-truth artefacts: {why}", file=sys.stderr)
    print(f"ground truth of {done}/{len(scenes)} scene(s) for {engine.cache_identity()} × "
          f"{sum(m.kind != 'scene' for m in metrics)} frame/sequence metric(s) in {store.root}: "
          f"{computed} value(s) computed, the rest already there "
          f"({time.perf_counter() - start:.1f} s)")
    return 0
