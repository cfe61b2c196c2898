"""The ground truth behind a finished run directory: its resolved config and its scenes.

A run directory keeps what the model produced (``scenes/<id>/video.mp4``, ``spec.json``…) but
not the ground truth, which stays in the dataset. Tools that look at a run afterwards (the
rating page shows the ground-truth clip beside the generated one; an intervention starts from
the model's S and the scene's world) read the dataset config the run recorded in
``config.yaml`` and load the same scenes from the data directory it used.
"""

from __future__ import annotations

import os
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from visphy_core.api.scene import Scene
from visphy_core.infra import files
from visphy_core.infra.errors import UserError
from visphy_core.results.layout import CONFIG, is_run_dir


def read_run_config(run_dir: Path) -> DictConfig:
    """The run's resolved config (`UserError` when ``run_dir`` is not a run directory)."""
    run_dir = Path(run_dir)
    if not is_run_dir(run_dir) or not (run_dir / CONFIG).is_file():
        raise UserError(f"{run_dir} is not a run directory (no {CONFIG} in it)")
    files.refuse_tree(run_dir, "run directory")
    try:
        cfg = OmegaConf.load(run_dir / CONFIG)
    except Exception as exc:  # noqa: BLE001 - any parse error is a damaged run directory
        raise UserError(f"{run_dir / CONFIG}: unreadable ({exc})") from None
    if not isinstance(cfg, DictConfig) or "dataset" not in cfg:
        raise UserError(f"{run_dir / CONFIG} names no dataset")
    return cfg


def run_data_dir(cfg: DictConfig) -> Path:
    """The data directory the run used; where it was relative to another working directory,
    the current ``$VISPHY_HOME/data``."""
    recorded = Path(str(OmegaConf.select(cfg, "paths.data_dir", default="") or "data"))
    here = Path(os.environ.get("VISPHY_HOME", "visphy-out")) / "data"
    for path in (recorded, here):
        if path.is_dir():
            return path.resolve()
    raise UserError(f"the run's data directory {recorded} is gone (and {here} does not exist): "
                    "set VISPHY_HOME to the folder whose data/ holds its dataset")


def load_run_scenes(run_dir: Path, scene_ids: list[str]) -> dict[str, Scene]:
    """The run's ground-truth scenes ``scene_ids``, by id, from the dataset it recorded."""
    from visphy_core.execute.datasets import load_dataset

    cfg = read_run_config(run_dir)
    dataset = OmegaConf.create(OmegaConf.to_container(cfg.dataset, resolve=True))
    dataset.scenes = sorted(set(scene_ids))
    dataset.limit = None
    dataset.shard = None  # a shard's run names its own scenes: sharding them again drops some
    try:
        scenes = load_dataset(dataset, run_data_dir(cfg), progress=False)
    except (ValueError, FileNotFoundError) as exc:
        raise UserError(f"{run_dir}: cannot load its dataset {cfg.dataset.get('name')!r}: "
                        f"{' '.join(str(exc).split())}") from None
    return {s.scene_id: s for s in scenes if s.scene_id in set(scene_ids)}
