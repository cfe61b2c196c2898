"""Dataset sources: which scenes a run evaluates. Each source is a dataset plugin
(`visphy_core.api.dataset.Dataset`, hook ``visphy_register_datasets``) selected by
``dataset.source``."""

from __future__ import annotations

from pathlib import Path

from visphy_core.api.scene import Scene
from visphy_core.infra.shard import parse_shard, select_shard


def get_dataset(source: str):
    """The dataset plugin registered as ``source`` (``ValueError`` naming the installed ones)."""
    from visphy_core.api.registry import get_registry

    datasets = get_registry().datasets
    if source not in datasets:
        raise ValueError(f"dataset.source={source!r} is not an installed dataset; valid: "
                         f"{', '.join(sorted(datasets)) or 'none installed'}")
    return datasets[source][0]()


def load_dataset(cfg, data_dir: Path, progress: bool = True) -> list[Scene]:
    """Scenes selected by the ``dataset`` config group (generated ones are built on first use).

    Dataset-level errors (missing root, unknown scene ids, empty selection) raise before any
    work; a scene whose own files are bad is kept and becomes a ``data_error`` row.
    """
    scenes = get_dataset(str(cfg.source)).load(cfg, Path(data_dir), progress=progress)
    if cfg.scenes:
        missing = sorted(set(cfg.scenes) - {s.scene_id for s in scenes})
        if missing:
            raise ValueError(f"dataset {cfg.name!r} has no scene(s) {', '.join(missing)}")
        wanted = set(cfg.scenes)  # here too: a plugin need not select them itself
        scenes = [s for s in scenes if s.scene_id in wanted]
    if cfg.limit is not None:
        scenes = scenes[: int(cfg.limit)]
    shard = parse_shard(cfg.get("shard"))
    if shard is not None:  # after the limit: the shards together are the unsharded selection
        scenes = select_shard(scenes, *shard)
    if not scenes:
        raise ValueError(f"dataset {cfg.name!r} selected no scenes (split={cfg.split!r}"
                         f"{f', shard={cfg.shard}' if shard else ''})")
    return scenes


def build_dataset(source: str, data_dir: Path, *, seed: int = 0, split: str | None = None,
                  workers: int = 1, progress: bool = True, **options) -> Path:
    """Generate dataset ``source`` under ``data_dir`` (``build-dataset``); its root."""
    return get_dataset(source).build(Path(data_dir), seed=seed, split=split, workers=workers,
                                     progress=progress, **options)
