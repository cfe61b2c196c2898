"""``dataset.source=generated``: VisPhyBench regenerated from its templates (built on first use)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from visphy_core.api.dataset import Dataset, FinishedRun, GroundTruth
from visphy_core.api.errors import ConfigError
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.scene import Scene
from visphy_core.api.settings import cfg_get
from visphy_plugins.datasets.layout import locate_in_layout
from visphy_plugins.datasets.visphybench.catalogue import GENERATOR_VERSION


def _listing(names: list[str], most: int = 12) -> str:
    if not names:
        return "none"
    more = f", … ({len(names) - most} more)" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def _version(node: Any) -> int:
    value = cfg_get(node, "version", None)
    return GENERATOR_VERSION if value is None else int(value)


def _existing_build(data_dir: Path, seed: int, version: int, lossless: bool) -> Path:
    """The root of an older generator version's build (loaded as it is: that generator is
    gone, so it cannot be rebuilt)."""
    from visphy_plugins.datasets.visphybench.build import dataset_root

    root = dataset_root(data_dir, seed, version, lossless)
    catalogue = root / "catalogue.json"
    builder = None
    if catalogue.is_file():
        try:
            builder = json.loads(catalogue.read_text()).get("builder")
        except (OSError, ValueError):
            builder = None
    if builder != f"visphy-bench/{version}" or not (root / "metadata.jsonl").is_file():
        raise ValueError(f"dataset.version={version}: no version-{version} build at {root} "
                         f"(this visphy generates version {GENERATOR_VERSION}; an older "
                         f"version can be loaded, not regenerated)")
    return root


class VisPhyBench(Dataset):
    name = "generated"
    description = ("VisPhyBench regenerated from its templates: 2D Box2D and 3D cannon-es "
                   "scenes, each rendered on first use by a run that selects it")
    #: ``dataset.scenes``, ``dataset.limit`` and ``dataset.shard`` are applied to the catalogue
    #: before anything is rendered: a run renders the ground truth of its own scenes only.
    selects = True

    def load(self, cfg: Any, data_dir: Path, progress: bool = True) -> list[Scene]:
        from visphy_core.api.selection import scene_traits, select_for
        from visphy_plugins.datasets.visphybench.build import (
            dataset_root,
            entry_traits,
            load_or_build_catalogue,
            render_scenes,
            split_entries,
        )
        from visphy_plugins.datasets.visphybench.loader import load_generated

        version = _version(cfg)
        lossless = bool(cfg_get(cfg, "lossless", False))
        seed = int(cfg.seed)
        if version != GENERATOR_VERSION:
            root = _existing_build(Path(data_dir), seed, version, lossless)
            return select_for(cfg, load_generated(root, split=cfg.split, strict=False),
                              scene_traits)
        root = dataset_root(Path(data_dir), seed, lossless=lossless)
        catalogue = load_or_build_catalogue(root, seed, progress=progress)
        entries = split_entries(catalogue, cfg.split)
        chosen = [e.spec["scene_id"] for e in select_for(cfg, entries, entry_traits)]
        render_scenes(root, catalogue, split=cfg.split, progress=progress, lossless=lossless,
                      scenes=None if len(chosen) == len(entries) else chosen)
        scenes = load_generated(root, split=cfg.split, scene_ids=chosen, strict=False)
        missing = sorted(set(chosen) - {s.scene_id for s in scenes})
        if missing:
            raise ValueError(f"{root / 'metadata.jsonl'} lacks scene(s) {_listing(missing)}, "
                             "rendered for this run")
        return scenes

    def build(self, data_dir: Path, *, seed: int = 0, split: str | None = None,
              workers: int = 1, progress: bool = True, lossless: bool = False,
              rebuild_catalogue: bool = False, scenes: list[str] | None = None,
              limit: int | None = None) -> Path:
        """``build-dataset``: the split's scenes, or those of them named (``scenes``) and
        ``limit`` of those (spread as a run's ``dataset.limit`` is)."""
        from visphy_core.api.selection import select_scenes
        from visphy_plugins.datasets.visphybench.build import (
            build_dataset,
            dataset_root,
            entry_traits,
            load_or_build_catalogue,
            render_scenes,
            split_entries,
        )

        if not scenes and limit is None:
            return build_dataset(data_dir, seed=seed, split=split, workers=workers,
                                 progress=progress, lossless=lossless,
                                 rebuild_catalogue=rebuild_catalogue)
        root = dataset_root(Path(data_dir), seed, lossless=lossless)
        catalogue = load_or_build_catalogue(root, seed, progress=progress, workers=workers,
                                            rebuild=rebuild_catalogue)
        entries = split_entries(catalogue, split)
        chosen = select_scenes(entries, entry_traits, scenes=scenes, limit=limit,
                               name=self.name, split=split)
        render_scenes(root, catalogue, split, [e.spec["scene_id"] for e in chosen],
                      progress=progress, workers=workers, lossless=lossless)
        return root

    def check(self, cfg: Any) -> None:
        """``dataset.split`` and ``dataset.scenes`` are checked against the catalogue: the one
        on disk, else the one shipped with visphy for this seed and generator version (else the
        run checks them once it is built)."""
        from visphy_plugins.datasets.visphybench.build import dataset_root

        root = OmegaConf.select(cfg, "dataset.root", default=None)
        if root not in (None, ""):
            raise ConfigError(f"dataset.root={root} is not used by the generated VisPhyBench "
                              f"(dataset.source=generated builds under paths.data_dir): set "
                              "paths.data_dir instead, or use dataset=original "
                              f"dataset.root={root} for the published layout")
        version = _version(OmegaConf.select(cfg, "dataset"))
        lossless = bool(OmegaConf.select(cfg, "dataset.lossless", default=False))
        data_dir = Path(str(OmegaConf.select(cfg, "paths.data_dir")))
        seed = int(OmegaConf.select(cfg, "dataset.seed", default=0) or 0)
        if version > GENERATOR_VERSION:
            raise ConfigError(f"dataset.version={version}: this visphy generates version "
                              f"{GENERATOR_VERSION} (and loads older builds)")
        if version < GENERATOR_VERSION:
            try:
                _existing_build(data_dir, seed, version, lossless)
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
        try:
            path = dataset_root(data_dir, seed, version, lossless) / "catalogue.json"
            if path.is_file():
                data = json.loads(path.read_text())
            elif version == GENERATOR_VERSION:
                from visphy_plugins.datasets.visphybench.shipped import shipped_bytes

                raw = shipped_bytes(seed)
                if raw is None:
                    return
                data = json.loads(raw)
            else:
                return
            if data.get("builder") != f"visphy-bench/{version}" or data.get("seed") != seed:
                return
            splits = {str(k): [str(i) for i in v] for k, v in data["splits"].items()}
            all_ids = sorted({str(s["spec"]["scene_id"]) for s in data["scenes"]})
        except Exception:  # noqa: BLE001 - anything odd: the run's own loading reports it
            return
        split = OmegaConf.select(cfg, "dataset.split", default=None)
        if split is not None and str(split) not in splits:
            raise ConfigError(f"dataset.split={split} is not a split of the generated benchmark; "
                              f"valid: {', '.join(sorted(splits))}")
        wanted = OmegaConf.select(cfg, "dataset.scenes", default=None)
        if wanted:
            valid = sorted(splits[str(split)]) if split is not None else all_ids
            missing = [str(s) for s in wanted if str(s) not in valid]
            if missing:
                where = f"split {split!r}" if split is not None else "the generated benchmark"
                raise ConfigError(f"dataset.scenes: {where} has no scene(s) "
                                  f"{', '.join(missing)}; valid: {_listing(valid)}")

    def locate_ground_truth(self, run: FinishedRun, scene_ids: list[str]) -> dict[str, GroundTruth]:
        """In the build folders under ``paths.data_dir`` (``visphybench-v3-seed0`` and the
        like), without building anything."""
        return locate_in_layout(run, scene_ids)


@hookimpl
def visphy_register_datasets(register):
    register(VisPhyBench.name, VisPhyBench)
