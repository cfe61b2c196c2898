"""A run's reference clips: its engine's trusted reference program renders the scene's stated
spec S and the twin through the render cache (`render_cache.py`), for scoring
(`visphy_core.scoring.scene_scores.ReferenceClips`)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from visphy_core.api.engine import Engine, Program, RenderContract
from visphy_core.api.scene import Scene
from visphy_core.execute.render_cache import (
    ENTRY_VIDEO,
    RenderOutcome,
    render_cached,
    render_key,
)
from visphy_core.infra.cache import Cache
from visphy_core.infra.errors import one_line
from visphy_core.infra.events import StageEvents
from visphy_core.results import layout
from visphy_core.results.write import write_artifact
from visphy_core.scoring.ground_truth import writable
from visphy_core.scoring.normalisation import twin_scene
from visphy_core.scoring.reference_clips import ReferenceClipUnavailable
from visphy_core.spec.spec_track import SpecTrackError, spec_scene

_write = write_artifact


class EngineReferenceClips:
    """`visphy_core.scoring.scene_scores.ReferenceClips` of a run: the engine's trusted reference
    program renders S and the twin (through the render cache) into the scene's folder. Each
    render goes through the ``render`` stage (the run's render lane). The twin's render goes to
    the ground-truth store when there is one (``ground_truth``), so later runs find it there."""

    def __init__(self, engine: Engine, cache: Cache, progress: StageEvents | None = None,
                 renders: dict[str, RenderOutcome] | None = None,
                 ground_truth: Cache | None = None):
        self.engine = engine
        self.cache = cache
        self.progress = progress or StageEvents()
        self.renders = renders
        self.twin_cache = ground_truth if writable(ground_truth) else cache
        self.stores = [c for c in (ground_truth, cache) if c is not None]
        self._twins: dict[str, Program] = {}
        self.render_s = 0.0  # wall seconds spent rendering (or reading back) clips here

    def _render(self, scene: Scene, program: Program, contract: RenderContract,
                cache: Cache | None = None) -> RenderOutcome:
        start = time.perf_counter()  # waiting for the render lane included
        try:
            with self.progress.stage("render", scene.scene_id):
                return render_cached(self.engine, program, contract, cache or self.cache,
                                     self.renders)
        finally:
            self.render_s += time.perf_counter() - start

    def spec_replay(self, scene: Scene, spec: dict, contract: RenderContract,
                    scene_dir: Path) -> np.ndarray:
        try:
            program = self.engine.program_from_spec(spec_scene(scene, spec))
        except (SpecTrackError, ValueError, NotImplementedError) as exc:
            raise ReferenceClipUnavailable(one_line(str(exc))) from None
        outcome = self._render(scene, program, contract)
        if outcome.failure is not None:
            raise ReferenceClipUnavailable(one_line(
                f"the reference program failed to replay S: {outcome.failure.value} "
                f"{outcome.error or ''}"))
        _write(scene_dir / layout.SPEC_VIDEO, outcome.video_path.read_bytes())
        return outcome.frames

    def _twin_program(self, scene: Scene) -> Program:
        if scene.scene_id not in self._twins:
            try:
                self._twins[scene.scene_id] = self.engine.program_from_spec(twin_scene(scene))
            except (SpecTrackError, ValueError, NotImplementedError) as exc:
                raise ReferenceClipUnavailable(
                    f"normalisation: no twin of the ground truth: {one_line(str(exc))}"
                ) from None
        return self._twins[scene.scene_id]

    def twin_identity(self, scene: Scene, contract: RenderContract) -> str:
        return render_key(self.engine, self._twin_program(scene), contract)

    def copy_twin(self, scene: Scene, contract: RenderContract, scene_dir: Path) -> bool:
        key = self.twin_identity(scene, contract)
        for store in self.stores:
            entry = store.get("render", key)
            if entry is not None and (entry / ENTRY_VIDEO).is_file():
                _write(scene_dir / layout.TWIN_VIDEO, (entry / ENTRY_VIDEO).read_bytes())
                return True
        return False

    def twin(self, scene: Scene, contract: RenderContract, scene_dir: Path | None
             ) -> np.ndarray:
        outcome = self._render(scene, self._twin_program(scene), contract, self.twin_cache)
        if outcome.failure is not None:
            raise ReferenceClipUnavailable(
                f"normalisation: the reference program failed to render the twin: "
                f"{outcome.failure.value} {one_line(outcome.error or '')}")
        if scene_dir is not None:
            _write(scene_dir / layout.TWIN_VIDEO, outcome.video_path.read_bytes())
        return outcome.frames
