"""Dataset sources: which scenes a run evaluates."""

from __future__ import annotations

from pathlib import Path

from visphy_core.scene import Scene

SOURCES = ("generated",)


def load_dataset(cfg, data_dir: Path, progress: bool = True) -> list[Scene]:
    """Scenes selected by the ``dataset`` config group (built on first use when generated)."""
    if cfg.source == "generated":
        from visphy_core.bench.build import ensure_dataset
        from visphy_core.dataset.generated import load_generated

        root = ensure_dataset(cfg.name, data_dir, progress=progress)
        scenes = load_generated(root, split=cfg.split, scene_ids=cfg.scenes)
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
