"""What a dataset plugin is: the scenes a run evaluates, from the ``dataset`` config node.

A plugin registers a factory under the name that ``dataset.source`` selects
(``visphy_register_datasets``: ``register("generated", VisPhyBench)``). The built-in ones are
``generated`` (VisPhyBench regenerated from its templates), ``original`` (the published
VisPhyBench-Data layout on disk) and ``tiny`` (a three-scene fixture for plugin authors).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from visphy_core.api.scene import Scene


class Dataset:
    """One source of scenes. Subclasses set ``name`` and ``description`` and implement `load`;
    `check` and `build` are optional."""

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
