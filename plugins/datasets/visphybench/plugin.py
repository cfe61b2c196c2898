"""``dataset.source=generated``: VisPhyBench regenerated from its templates (built on first use)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from visphy_core.dataset.base import Dataset
from visphy_core.errors import ConfigError
from visphy_core.hookspecs import hookimpl
from visphy_core.scene import Scene


def _listing(names: list[str], most: int = 12) -> str:
    if not names:
        return "none"
    more = f", … ({len(names) - most} more)" if len(names) > most else ""
    return ", ".join(names[:most]) + more


class VisPhyBench(Dataset):
    name = "generated"
    description = ("VisPhyBench regenerated from its templates: 2D Box2D and 3D cannon-es "
                   "scenes, simulated on first use and rendered per split")

    def load(self, cfg: Any, data_dir: Path, progress: bool = True) -> list[Scene]:
        from visphy_plugins.datasets.visphybench.build import build_dataset
        from visphy_plugins.datasets.visphybench.loader import load_generated

        root = build_dataset(data_dir, seed=cfg.seed, split=cfg.split, progress=progress)
        return load_generated(root, split=cfg.split, scene_ids=cfg.scenes, strict=False)

    def build(self, data_dir: Path, *, seed: int = 0, split: str | None = None,
              workers: int = 1, progress: bool = True) -> Path:
        from visphy_plugins.datasets.visphybench.build import build_dataset

        return build_dataset(data_dir, seed=seed, split=split, workers=workers,
                             progress=progress)

    def check(self, cfg: Any) -> None:
        """Where the catalogue is already on disk, ``dataset.split`` and ``dataset.scenes`` are
        checked against it (else the run checks them once it is built)."""
        from visphy_plugins.datasets.visphybench.build import BUILDER_VERSION, dataset_root

        try:
            data_dir = OmegaConf.select(cfg, "paths.data_dir")
            seed = int(OmegaConf.select(cfg, "dataset.seed", default=0) or 0)
            path = dataset_root(Path(str(data_dir)), seed) / "catalogue.json"
            if not path.is_file():
                return
            data = json.loads(path.read_text())
            if data.get("builder") != BUILDER_VERSION or data.get("seed") != seed:
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


@hookimpl
def visphy_register_datasets(register):
    register(VisPhyBench.name, VisPhyBench)
