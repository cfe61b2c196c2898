"""Dataset sources: which scenes a run evaluates."""

from __future__ import annotations

from pathlib import Path

from visphy_core.scene import Scene

SOURCES = ("generated", "original")


def load_dataset(cfg, data_dir: Path, progress: bool = True) -> list[Scene]:
    """Scenes selected by the ``dataset`` config group (generated ones are built on first use).

    Dataset-level errors (missing root, unknown scene ids, empty selection) raise before any
    work; a scene whose own files are bad is kept and becomes a ``data_error`` row.
    """
    if cfg.source == "generated":
        from visphy_core.bench.build import build_dataset
        from visphy_core.dataset.generated import load_generated

        root = build_dataset(data_dir, seed=cfg.seed, split=cfg.split, progress=progress)
        scenes = load_generated(root, split=cfg.split, scene_ids=cfg.scenes, strict=False)
    elif cfg.source == "original":
        from visphy_core.dataset.original import load_original

        if not cfg.root:
            raise ValueError("dataset.source=original needs dataset.root (the folder holding "
                             "<split>/videos; or set VISPHYBENCH_ROOT)")
        scenes = load_original(Path(cfg.root), split=cfg.split or "sub", scene_ids=cfg.scenes,
                               strict=False)
    else:
        raise ValueError(f"dataset.source={cfg.source!r} is not a known source; "
                         f"valid: {', '.join(SOURCES)}")
    if cfg.scenes:
        missing = sorted(set(cfg.scenes) - {s.scene_id for s in scenes})
        if missing:
            raise ValueError(f"dataset {cfg.name!r} has no scene(s) {', '.join(missing)}")
    if cfg.limit is not None:
        scenes = scenes[: int(cfg.limit)]
    if not scenes:
        raise ValueError(f"dataset {cfg.name!r} selected no scenes (split={cfg.split!r})")
    return scenes
