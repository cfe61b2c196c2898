"""A tiny benchmark in the original VisPhyBench-Data layout, for tests of visphy and its plugins.

``make_tiny_dataset(root, n_scenes)`` writes ``root/<split>/videos/<id>.mp4`` (64×64, 17 frames at
5 fps: a coloured square falling), ``detection_json/<id>_frame_01.json`` and ``metadata.jsonl``;
use it with ``dataset=original dataset.root=<root> dataset.split=<split>``. Scenes are 2D ids
(``task1000N_000``) whose clips differ in colour and speed, so per-scene results differ.

It is also a dataset plugin of its own, the smallest complete example of one for plugin authors:
``dataset=tiny`` (``dataset.source=tiny``) writes three scenes under ``<paths.data_dir>/tiny`` on
first use and loads them with the published layout's loader.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from visphy_core.api.dataset import Dataset, FinishedRun, GroundTruth
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.media import encode_video
from visphy_core.api.scene import Scene
from visphy_plugins.datasets.layout import locate_in_layout

SIZE, N_FRAMES, FPS = 64, 17, 5


def tiny_clip(index: int) -> np.ndarray:
    """The clip of scene ``index``: a 12-px square falling at a speed that depends on index."""
    frames = np.full((N_FRAMES, SIZE, SIZE, 3), 255, dtype=np.uint8)
    colour = ((37 * index) % 200 + 30, 80, 255 - (37 * index) % 200)
    for k in range(N_FRAMES):
        y = min(SIZE - 14, 2 + k * (2 + index % 3))
        x = 6 + (5 * index) % (SIZE - 20)
        frames[k, y:y + 12, x:x + 12] = colour
    return frames


def scene_id(index: int) -> str:
    return f"task{10000 + index:05d}_000"


def make_tiny_dataset(root: Path, n_scenes: int = 3, split: str = "sub") -> Path:
    """Write the dataset; returns ``root`` (pass it as ``dataset.root``)."""
    d = Path(root) / split
    (d / "videos").mkdir(parents=True, exist_ok=True)
    (d / "detection_json").mkdir(exist_ok=True)
    lines = []
    for i in range(n_scenes):
        sid = scene_id(i)
        encode_video(tiny_clip(i), d / "videos" / f"{sid}.mp4", FPS)
        detection = {"image_size": {"width": SIZE, "height": SIZE},
                     "coordinate_system": "pixels, origin top-left, y down",
                     "objects": [{"id": "falling_square", "category": "rectangle",
                                  "color_rgb": [int(c) for c in tiny_clip(i)[0].reshape(-1, 3)
                                                .min(axis=0)]}]}
        (d / "detection_json" / f"{sid}_frame_01.json").write_text(json.dumps(detection))
        lines.append(json.dumps({"id": sid, "fps": FPS, "n_frames": N_FRAMES,
                                 "width": SIZE, "height": SIZE, "difficulty": "easy"}))
    (d / "metadata.jsonl").write_text("\n".join(lines) + "\n")
    return Path(root)


class TinyDataset(Dataset):
    """``dataset.source=tiny``: three 64×64 falling squares (no specs: no spec track, no
    variance normalisation; every other metric runs)."""

    name = "tiny"
    description = "three 64×64 falling squares in the published layout (a fixture)"
    n_scenes = 3

    def load(self, cfg, data_dir: Path, progress: bool = True) -> list[Scene]:
        from visphy_plugins.datasets.original import load_original

        root = Path(data_dir) / "tiny"
        split = cfg.split or "sub"
        if not (root / split / "metadata.jsonl").is_file():
            make_tiny_dataset(root, self.n_scenes, split=split)
        return load_original(root, split=split, scene_ids=cfg.scenes, strict=False)

    def locate_ground_truth(self, run: FinishedRun, scene_ids: list[str]) -> dict[str, GroundTruth]:
        return locate_in_layout(run, scene_ids)


@hookimpl
def visphy_register_datasets(register):
    register(TinyDataset.name, TinyDataset)
