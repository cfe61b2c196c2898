"""Dataset ``example_squares``: three 48×48 squares falling, written on first use.

``dataset=tiny dataset.source=example_squares`` selects it (any ``dataset`` entry will do:
``source`` names the plugin). `load` returns one `Scene` per clip: its id, its ground-truth
video, its detection context and its clip contract, for the scenes ``dataset.scenes`` names (all
of them when it is empty). The core then checks that every named id was returned and applies
``dataset.limit`` and ``dataset.shard``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from visphy_core.api.dataset import Dataset
from visphy_core.api.errors import ConfigError
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.media import ClipInfo, encode_video
from visphy_core.api.scene import Scene

SIZE, N_FRAMES, FPS = 48, 12, 6
SCENE_IDS = [f"task{20000 + i:05d}_000" for i in range(3)]  # the published layout's 2D ids


def clip(index: int) -> np.ndarray:
    """A 10-px square falling from rest at 60 + 30·index px/s² (y down)."""
    frames = np.full((N_FRAMES, SIZE, SIZE, 3), 255, np.uint8)
    for k in range(N_FRAMES):
        y = min(SIZE - 10, round(2 + 0.5 * (60 + 30 * index) * (k / FPS) ** 2))
        frames[k, y:y + 10, 19:29] = (200, 40 * index, 40)
    return frames


class SquaresDataset(Dataset):
    name = "example_squares"
    description = "three 48×48 falling squares (the example plugin)"

    def check(self, cfg) -> None:
        # cheap checks of the whole run config before any work: one line, exit status 2
        unknown = set(cfg.dataset.get("scenes") or ()) - set(SCENE_IDS)
        if unknown:
            raise ConfigError(f"dataset.scenes: {', '.join(sorted(unknown))} not in "
                              f"example_squares ({', '.join(SCENE_IDS)})")

    def load(self, cfg, data_dir: Path, progress: bool = True) -> list[Scene]:
        root = Path(data_dir) / self.name
        root.mkdir(parents=True, exist_ok=True)
        wanted = set(cfg.get("scenes") or SCENE_IDS)  # the plugin selects dataset.scenes
        scenes = []
        for i, sid in enumerate(SCENE_IDS):
            if sid not in wanted:
                continue
            video, detection = root / f"{sid}.mp4", root / f"{sid}_detection.json"
            if not video.is_file():
                encode_video(clip(i), video, FPS)
                detection.write_text(json.dumps({
                    "image_size": {"width": SIZE, "height": SIZE},
                    "objects": [{"id": "square", "category": "rectangle"}]}))
            scenes.append(Scene(scene_id=sid, dim="2d", video_path=video,
                                clip=ClipInfo(fps=FPS, n_frames=N_FRAMES, width=SIZE,
                                              height=SIZE),
                                detection_path=detection, dataset=self.name))
        return scenes


@hookimpl
def visphy_register_datasets(register):
    register(SquaresDataset.name, SquaresDataset)  # factory() -> Dataset
