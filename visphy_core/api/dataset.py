"""What a dataset plugin is: the scenes a run evaluates, from the ``dataset`` config node.

A plugin registers a factory under the name that ``dataset.source`` selects
(``visphy_register_datasets``: ``register(name, factory)``); the built-in ones are in
``plugins/datasets/`` (``visphy plugins`` lists every installed one). A dataset also tells the
report where a finished run's ground truth lies (`Dataset.locate_ground_truth`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from visphy_core.api.scene import Scene


@dataclass
class GroundTruth:
    """Where one scene's ground truth lies (paths that exist), or why it was not found."""

    scene_id: str
    root: Path | None = None
    video: Path | None = None
    keyframes: dict[int, Path] = field(default_factory=dict)
    spec: Path | None = None
    detection: Path | None = None
    missing: str | None = None


@dataclass(frozen=True)
class FinishedRun:
    """What a dataset reads of a finished run to find its ground truth: ``cfg`` reads a dotted
    key of the run's config (``cfg("dataset.root", None)``); ``paths`` turns a path the config
    names into the folders it may be (a relative one is relative to where the run was started,
    or to the current directory)."""

    cfg: Callable[[str, Any], Any]
    paths: Callable[[object], list[Path]]


class Dataset:
    """One source of scenes. Subclasses set ``name`` and ``description`` and implement `load`;
    `check`, `build` and `locate_ground_truth` are optional."""

    name: str = ""
    description: str = ""
    #: True when `load` applies ``dataset.scenes``, ``dataset.limit`` and ``dataset.shard``
    #: itself (`visphy_core.api.selection.select_for` over its own listing, so that it builds
    #: only the scenes chosen) and returns exactly those; False: it returns the whole split and
    #: the core selects.
    selects: bool = False

    def load(self, cfg: Any, data_dir: Path, progress: bool = True) -> list[Scene]:
        """Every scene of the selected split, or only the selected ones when `selects` is set
        (``cfg`` is the ``dataset`` node; ``data_dir`` is ``paths.data_dir``, where generated
        data lives). Dataset-level problems (a missing root, an unknown split) raise
        ``ValueError`` with one line; a scene whose own files are bad is returned with its
        ``load_error`` set (it becomes a ``data_error`` row, never a gap)."""
        raise NotImplementedError

    def check(self, cfg: Any) -> None:
        """Cheap checks of the ``dataset`` node before any work (files named exist, the split
        and scene ids are known where that is already on disk); raise
        `visphy_core.api.errors.ConfigError` with one line. The whole run config is ``cfg``."""

    def build(self, data_dir: Path, *, seed: int = 0, split: str | None = None,
              workers: int = 1, progress: bool = True, **options: Any) -> Path:
        """Generate the data under ``data_dir`` (``build-dataset``); returns its root. Only
        generated datasets implement it; ``options`` are their own (``lossless=True``)."""
        raise NotImplementedError(f"dataset {self.name!r} is not generated: nothing to build")

    def locate_ground_truth(self, run: FinishedRun, scene_ids: list[str]) -> dict[str, GroundTruth]:
        """Where each scene's ground truth lies on disk, for the report of a finished ``run``,
        found without loading or building anything (a report must not regenerate a
        benchmark). A scene left out, or returned with ``missing`` (the reason: where it
        looked), is reported as not found. Default: none is found."""
        return {}
