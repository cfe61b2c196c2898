"""The ground-truth store (`visphy_core.scoring.ground_truth`): normalisation anchors computed ahead
of a run (``ground-truth``) are the anchors a run computes itself; a run that finds them renders one
clip per oracle scene (no twin, the spec track's replay is the program's render) and scores no
anchor; entries are keyed by what determines them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from visphy_core.api.engine import RenderContract
from visphy_core.infra.cache import Cache
from visphy_core.scoring.ground_truth import (
    CEILING,
    FLOOR,
    anchor_key,
    frozen_identity,
    scene_anchors,
)

METRICS = ["metrics.names=[psnr,spatiotemporal_iou,track_pos_err]", "metrics.spec_track=true",
           "metrics.variance_norm=true"]


def _entries(root: Path, kind: str) -> dict[str, bytes]:
    return {p.parent.name: p.read_bytes() for p in sorted((root / kind).glob("*/*/*"))
            if p.name != ".complete" and p.parent.parent.parent.name == kind}


def _summary(run_dir: Path) -> dict:
    return json.loads((run_dir / "summary.json").read_text())


def _run(home: Path, tmp: Path, name: str, scene_id: str, store: Path) -> tuple[Path, list]:
    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment

    cfg = compose([f"paths.root={home}", "tracking=none", "run.progress=false",
                   f"paths.cache_dir={tmp / name / 'cache'}",
                   f"paths.runs_dir={tmp / name / 'runs'}",
                   f"paths.ground_truth_dir={store}", f"dataset.scenes=[{scene_id}]", *METRICS])
    run_dir = Path(run_experiment(cfg)["run_dir"])
    rows = [json.loads(line) for line in (run_dir / "results.jsonl").open()]
    return run_dir, rows


@pytest.mark.browser
def test_anchors_built_ahead_are_the_run_time_anchors_and_a_run_reuses_them(
        tmp_path, mini_root, mini_scenes):
    from visphy_core.execute.prepare_truth import prepare

    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    scene = mini_scenes[0].scene_id
    # a run with an empty store computes the anchors and the twin's render, and stores them
    first_dir, first = _run(home, tmp_path, "first", scene, tmp_path / "gt_run")
    run_anchors = _entries(tmp_path / "gt_run", "anchor")
    assert len(run_anchors) == 2 * 3  # floor and ceiling of each metric
    assert len(_entries(tmp_path / "first" / "cache", "render")) == 1  # the program only
    # by the run's ground-truth stage, before its scene was scored: the scoring found them
    assert json.loads((first_dir / "scenes" / scene / "normalisation.json").read_text())[
        "anchors_from"].startswith("stored")
    filled = _summary(first_dir)["ground_truth"]
    assert (filled["computed_now"], filled["reused"], filled["values_computed"]) == (1, 0, 6)
    assert filled["wall_s"] > 0 and filled["failed"] == []

    # built ahead, from another cache: the same entries, byte for byte
    assert prepare([f"paths.root={home}", f"paths.cache_dir={tmp_path / 'prep-cache'}",
                    f"paths.ground_truth_dir={tmp_path / 'gt_built'}",
                    f"dataset.scenes=[{scene}]", *METRICS], workers=2, progress=False) == 0
    assert _entries(tmp_path / "gt_built", "anchor") == run_anchors
    assert _entries(tmp_path / "gt_built", "render").keys() == \
        _entries(tmp_path / "gt_run", "render").keys()

    # a cold-cache run on the built store: same row, one render, nothing scored for anchors
    again_dir, again = _run(home, tmp_path, "again", scene, tmp_path / "gt_built")
    scores = lambda row: {k: v for k, v in row.items() if k.startswith("score_")}  # noqa: E731
    assert scores(again[0]) == scores(first[0])
    assert again[0]["score_norm.psnr"] is not None
    assert len(_entries(tmp_path / "again" / "cache", "render")) == 1
    norm = json.loads((again_dir / "scenes" / scene / "normalisation.json").read_text())
    assert norm["anchors_from"].startswith("stored")
    assert (again_dir / "scenes" / scene / "twin_video.mp4").read_bytes() == \
        (first_dir / "scenes" / scene / "twin_video.mp4").read_bytes()
    assert _entries(tmp_path / "gt_built", "anchor") == run_anchors  # nothing added
    filled = _summary(again_dir)["ground_truth"]  # the scene's mark: found without a lookup
    assert (filled["computed_now"], filled["reused"], filled["values_computed"]) == (0, 1, 0)


def test_without_normalisation_only_the_headline_floors_are_built(tmp_path, mini_root,
                                                                  mini_scenes):
    """The default (metrics.variance_norm=false): `ground-truth` builds what such a run reads,
    the headline component's floor (the still clip's score), no twin and no other anchor."""
    from visphy_core.execute.prepare_truth import prepare

    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    scene = mini_scenes[0].scene_id
    assert prepare([f"paths.root={home}", f"paths.cache_dir={tmp_path / 'cache'}",
                    f"paths.ground_truth_dir={tmp_path / 'gt'}", f"dataset.scenes=[{scene}]",
                    "metrics.names=[psnr,spatiotemporal_iou_tol]"], progress=False) == 0
    assert len(_entries(tmp_path / "gt", "anchor")) == 1
    assert not _entries(tmp_path / "gt", "render")


class _Clips:
    """A ReferenceClips whose twin is a given clip (the test's own, known by its content)."""

    def __init__(self, twin: np.ndarray):
        self.frames, self.rendered = twin, 0

    def twin_identity(self, scene, contract):
        return None

    def twin(self, scene, contract, scene_dir):
        self.rendered += 1
        return self.frames

    def copy_twin(self, scene, contract, scene_dir):
        return False


def test_stored_anchors_are_served_and_keyed_by_what_determines_them(tmp_path, mini_scenes):
    from visphy_core.api.registry import get_registry

    scene = mini_scenes[0]
    reference = scene.reference_frames()
    contract = RenderContract.for_scene(scene)
    metric = get_registry().get("metrics", "psnr")
    twin = reference.copy()
    twin[:, 0, 0] = 0  # one pixel off the ground truth: a finite ceiling
    store, cache = Cache(tmp_path / "gt"), Cache(tmp_path / "cache")
    clips = _Clips(twin)
    first = scene_anchors(scene, reference, [metric], clips, contract, cache, store, None)
    assert first.computed == 2 and clips.rendered == 1
    assert first.floor["psnr"] < first.ceiling["psnr"]
    again = scene_anchors(scene, reference, [metric], clips, contract, Cache(tmp_path / "c2"),
                          store, None)
    assert again.computed == 0 and (again.floor, again.ceiling) == (first.floor, first.ceiling)
    assert not (tmp_path / "c2" / "anchor").exists()  # served from the store

    # what changes a value changes the key
    ident = frozen_identity(scene, contract)
    key = anchor_key(FLOOR, ident, "ref", metric)
    assert anchor_key(CEILING, ident, "ref", metric) != key
    assert anchor_key(FLOOR, ident, "other-ref", metric) != key
    newer = type(metric)()
    newer.version = metric.version + ".1"
    assert anchor_key(FLOOR, ident, "ref", newer) != key
    longer = RenderContract(fps=contract.fps, n_frames=contract.n_frames + 1,
                            width=contract.width, height=contract.height, dim=contract.dim)
    assert frozen_identity(scene, longer) != ident
    # the time limit does not change a clip
    assert frozen_identity(scene, RenderContract.for_scene(scene, timeout_s=5.0)) == ident

    # a scene's completion mark: another metric, contract or ceiling is another mark
    from visphy_core.execute.prepare_truth import complete_key

    class _Engine:
        def cache_identity(self):
            return "engine/1"

    mark = complete_key(scene, _Engine(), [metric], contract, True)
    assert mark == complete_key(scene, _Engine(), [metric], contract, True)
    assert complete_key(scene, _Engine(), [metric, newer], contract, True) != mark
    assert complete_key(scene, _Engine(), [metric], longer, True) != mark
    assert complete_key(scene, _Engine(), [metric], contract, False) != mark


def test_the_subcommand_reports_bad_overrides_in_one_line(tmp_path):
    from conftest import run_cli

    proc = run_cli("ground-truth", "engine=nope", home=tmp_path, check=False)
    assert proc.returncode == 2
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("error: ") and "engine" in line
    assert "ground-truth" in run_cli("ground-truth", "--help", home=tmp_path).stdout
