"""The stages a scene goes through and the events a scene reports on its way: the pipeline
enters every stage through `StageEvents.stage`; the console shows them
(`visphy_core.execute.console.StageProgress`) and the scheduler's gates pace them
(`visphy_core.execute.scheduler.StageGates`)."""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

#: A scene's stages, in the order they run: the model's reply, its render, metrics, judges.
STAGES = ("generate", "render", "score", "judge")


class StageEvents:
    """What the pipeline reports while a scene goes through its stages. This base class
    ignores everything (no progress wanted); `StageProgress` shows it. The scheduler's gates
    (`visphy_core.execute.scheduler.StageGates`) hold a scene at a stage's entrance until the
    stage's resources are free, so the pipeline enters every stage through `stage`."""

    def begin(self, stage: str, scene_id: str) -> None:
        """``scene_id`` entered ``stage`` (again, for a repair: the time adds up)."""

    def end(self, stage: str, scene_id: str) -> None:
        """``scene_id`` left ``stage``; the first end counts the scene as done there."""

    def scene_finished(self, scene_id: str) -> None:
        """The scene is finished: stages it never reached count as skipped."""

    def check(self) -> None:
        """Between two steps of a stage: raises when the run is closing (the scheduler's
        gates); here, nothing."""

    @contextmanager
    def stage(self, stage: str, scene_id: str) -> Iterator[None]:
        """``begin`` … ``end`` around the block (no ``end`` when the block raises: the scene's
        `scene_finished` closes what it left open)."""
        self.begin(stage, scene_id)
        yield
        self.end(stage, scene_id)
