"""Clips of visphy's trusted reference program for one scene, and where they come from.

Scoring a scene needs clips that the model did not make: the frozen clip (the first key frame
held: the fallback and the normalisation floor), the ground truth's twin (the ceiling) and S
replayed (the spec track). A run renders the last two with its engine
(`visphy_core.execute.pipeline.EngineReferenceClips`); re-scoring reads them back from the run
directory (`visphy_core.execute.rescore.RunDirClips`). `ReferenceClips` is that seam.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Protocol

import numpy as np

from visphy_core.api.engine import RenderContract
from visphy_core.api.scene import Scene
from visphy_core.infra.video import decode_video, encode_video


def frozen_clip(scene: Scene, contract: RenderContract, path: Path) -> np.ndarray:
    """The first key frame held for the whole clip, through the run's video codec (written to
    ``path``): the fallback clip and the normalisation floor."""
    frames = np.repeat(scene.key_frame(1)[None], contract.n_frames, axis=0)
    encode_video(frames, path, contract.fps)
    return decode_video(path)[0]


class ReferenceClipUnavailable(Exception):
    """The reference program's clip could not be had; the message says why (one line)."""


class ReferenceClips(Protocol):
    """Clips of visphy's trusted reference program for one scene."""

    def spec_replay(self, scene: Scene, spec: dict, contract: RenderContract,
                    scene_dir: Path) -> np.ndarray:
        """S simulated and replayed (``spec_video.mp4``); raises `ReferenceClipUnavailable`."""

    def twin(self, scene: Scene, contract: RenderContract, scene_dir: Path | None
             ) -> np.ndarray:
        """The ground truth's twin (written to ``scene_dir/twin_video.mp4`` when a folder is
        given); raises `ReferenceClipUnavailable`."""

    def twin_identity(self, scene: Scene, contract: RenderContract) -> str | None:
        """What the twin's frames are a function of (its render key), without rendering it;
        None when only its content can say (`visphy_core.scoring.ground_truth`). Raises
        `ReferenceClipUnavailable` when there is no twin to be had."""

    def copy_twin(self, scene: Scene, contract: RenderContract, scene_dir: Path) -> bool:
        """``scene_dir/twin_video.mp4`` from a stored render of the twin, without rendering
        or decoding; False when none is stored."""


def frozen_frames(scene: Scene, contract: RenderContract,
                  frozen: np.ndarray | None = None) -> np.ndarray:
    """``frozen`` (the run's fallback clip, when the scene fell back), else the frozen clip made
    now through the run's codec (`frozen_clip`) in a scratch folder."""
    if frozen is not None:
        return frozen
    with tempfile.TemporaryDirectory(prefix="visphy-frozen-") as tmp:
        return frozen_clip(scene, contract, Path(tmp) / "frozen.mp4")
