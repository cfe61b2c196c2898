"""The report's ground-truth look-up (`visphy_core.report.locate_truth`): a scene whose data
folder is gone says where it looked, including the folder the config names."""

from __future__ import annotations

from pathlib import Path

from visphy_core.report.locate_truth import locate_ground_truth
from visphy_core.results.load import RunData


def _run(tmp_path: Path, config: dict) -> RunData:
    run_dir = tmp_path / "runs" / "r"
    run_dir.mkdir(parents=True)
    return RunData(run_dir=run_dir, config=config, manifest={}, summary={}, results=[])


def test_a_moved_data_folder_is_named_in_the_reason(tmp_path):
    gone = tmp_path / "deleted-data"
    run = _run(tmp_path, {"paths": {"data_dir": str(gone), "runs_dir": "runs"},
                          "dataset": {"name": "mini"}})
    found = locate_ground_truth(run, ["s1"])["s1"]
    assert found.video is None
    assert f"under {gone} (missing)" in found.missing
    assert "config names no data folder" not in found.missing


def test_a_found_scene_and_a_config_without_data_folder(tmp_path):
    data = tmp_path / "data" / "build"
    (data / "videos").mkdir(parents=True)
    (data / "videos" / "s1.mp4").write_bytes(b"")
    run = _run(tmp_path, {"paths": {"data_dir": str(tmp_path / "data")}})
    got = locate_ground_truth(run, ["s1", "s2"])
    assert got["s1"].video == data / "videos" / "s1.mp4" and got["s1"].missing is None
    assert f"under {tmp_path / 'data'} (dataset" in got["s2"].missing
    bare = locate_ground_truth(_run(tmp_path / "b", {}), ["s1"])["s1"]
    assert "nowhere (the config names no data folder)" in bare.missing
