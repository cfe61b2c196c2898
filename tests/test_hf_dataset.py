"""`visphy export-dataset --format hf` and `dataset=hf`: the generated `mini` split as a Hugging
Face `datasets` folder, loaded by `datasets` with every field, and read back by visphy as the
same scenes (the same bytes), so a run on it gives the same scores."""

from __future__ import annotations

import io
import json
import shutil

import numpy as np
import pytest
from omegaconf import OmegaConf

from conftest import run_cli
from visphy_core.cli.main import main
from visphy_plugins.datasets.hf import HFDataset

MINI = 4
SCENE = "vpb3-s0-2d-t001-v00"


@pytest.fixture(scope="module")
def exported(tmp_path_factory, mini_root):
    """The mini split exported (from a copy of the session's build, which stays untouched)."""
    data = tmp_path_factory.mktemp("data")
    shutil.copytree(mini_root, data / mini_root.name)
    out = tmp_path_factory.mktemp("hf") / "visphybench-mini"
    assert main(["export-dataset", "--format", "hf", "-o", str(out), "dataset=mini",
                 f"paths.data_dir={data}"]) == 0
    return out


def test_datasets_loads_every_scene_with_every_field(exported, mini_scenes):
    datasets = pytest.importorskip("datasets")
    ds = datasets.load_dataset(str(exported))
    assert list(ds) == ["mini"] and ds["mini"].num_rows == MINI
    by_id = {s.scene_id: s for s in mini_scenes}
    for row in ds["mini"]:
        scene = by_id[row["scene_id"]]
        assert (row["dim"], row["difficulty"], row["template"]) == (
            scene.dim, scene.difficulty, scene.template_id)
        assert (row["n_frames"], row["width"], row["fps"]) == (
            scene.clip.n_frames, scene.clip.width, scene.clip.fps)
        assert np.array_equal(np.asarray(row["frame_10"].convert("RGB")), scene.key_frame(10))
        assert json.loads(row["spec"]) == scene.spec
        assert json.loads(row["detection"]) == scene.detection
        assert json.loads(row["ground_truth"]) == scene.spec["ground_truth"]
        assert (exported / row["video"]).read_bytes() == scene.video_path.read_bytes()
        traj = np.load(io.BytesIO((exported / row["trajectory"]).read_bytes()))
        assert set(traj.files) == set(scene.trajectory)
    card = (exported / "README.md").read_text()
    assert "## Datasheet" in card and "path: data/mini-*.parquet" in card


def test_dataset_hf_reads_back_the_same_files(exported, mini_scenes, tmp_path):
    cfg = OmegaConf.create({"root": str(exported), "split": None})
    scenes = HFDataset().load(cfg, tmp_path)
    assert [s.scene_id for s in scenes] == [s.scene_id for s in mini_scenes]
    for got, want in zip(scenes, mini_scenes):
        assert (got.dim, got.clip, got.difficulty, got.template_id) == (
            want.dim, want.clip, want.difficulty, want.template_id)
        for name in ("video_path", "detection_path", "spec_path", "trajectory_path"):
            assert getattr(got, name).read_bytes() == getattr(want, name).read_bytes(), name
        for k in (1, 10):
            assert got.keyframe_paths[k].read_bytes() == want.keyframe_paths[k].read_bytes()


def test_dataset_hf_names_its_splits_and_needs_a_root(exported, tmp_path):
    from visphy_core.api.errors import ConfigError

    with pytest.raises(ConfigError, match="dataset.root=DIR"):
        HFDataset().load(OmegaConf.create({"root": None, "split": None}), tmp_path)
    with pytest.raises(ConfigError, match="has mini"):
        HFDataset().load(OmegaConf.create({"root": str(exported), "split": "test"}), tmp_path)


@pytest.mark.browser
def test_a_run_on_the_export_gives_the_generated_datasets_rows(exported, visphy_home, tmp_path):
    """Two homes, so that nothing is shared through the cache: the same oracle run on the
    generated mini split and on its export scores the same."""
    scores = []
    for home, dataset in ((visphy_home, ["dataset=mini"]),
                          (tmp_path / "fresh", ["dataset=hf", f"dataset.root={exported}"])):
        run_cli("model=oracle", "engine=threejs", *dataset, f"dataset.scenes=[{SCENE}]",
                "tracking=none", home=home)
        (results,) = (home / "runs").glob("*/results.jsonl")
        row = json.loads(results.read_text().splitlines()[0])
        assert row["scene_id"] == SCENE and row["system_success"]
        scores.append({k: v for k, v in row.items() if k.startswith("score_")})
    assert scores[0] and scores[0] == scores[1]
