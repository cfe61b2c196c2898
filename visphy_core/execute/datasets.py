"""Dataset sources: which scenes a run evaluates. Each source is a dataset plugin
(`visphy_core.api.dataset.Dataset`, hook ``visphy_register_datasets``) selected by
``dataset.source``."""

from __future__ import annotations

from pathlib import Path

from visphy_core.api.scene import Scene
from visphy_core.api.selection import scene_traits, select_for


def get_dataset(source: str):
    """The dataset plugin registered as ``source`` (``ValueError`` naming the installed ones)."""
    from visphy_core.api.registry import get_registry

    datasets = get_registry().datasets
    if source not in datasets:
        raise ValueError(f"dataset.source={source!r} is not an installed dataset; valid: "
                         f"{', '.join(sorted(datasets)) or 'none installed'}")
    return datasets[source][0]()


def load_dataset(cfg, data_dir: Path, progress: bool = True) -> list[Scene]:
    """Scenes selected by the ``dataset`` config group (generated ones are built on first use):
    ``dataset.scenes``, then ``dataset.limit`` spread over the split's dimensions, difficulties
    and templates, then ``dataset.shard`` (`visphy_core.api.selection`).

    Dataset-level errors (missing root, unknown scene ids, empty selection) raise before any
    work; a scene whose own files are bad is kept and becomes a ``data_error`` row. A plugin
    that selects for itself (``Dataset.selects``: it builds only what it chose) is trusted with
    the selection; any other returns its whole split and is narrowed here.
    """
    dataset = get_dataset(str(cfg.source))
    scenes = dataset.load(cfg, Path(data_dir), progress=progress)
    if not getattr(dataset, "selects", False):
        return select_for(cfg, scenes, scene_traits)
    if not scenes:
        raise ValueError(f"dataset {cfg.name!r} selected no scenes (split={cfg.split!r})")
    return scenes


def build_dataset(source: str, data_dir: Path, *, seed: int = 0, split: str | None = None,
                  workers: int = 1, progress: bool = True, **options) -> Path:
    """Generate dataset ``source`` under ``data_dir`` (``build-dataset``); its root."""
    return get_dataset(source).build(Path(data_dir), seed=seed, split=split, workers=workers,
                                     progress=progress, **options)
