"""``merge``: the shards of one run (a ``dataset.shard=0/2,1/2`` multirun of the tiny dataset)
merged into one run equal to the unsharded run (rows, order, summary, config hash), with one
MLflow run that is the shards' parent and the study's child; and every refusal (other configs,
a scene twice, a shard missing or unfinished, an existing output) as one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml

from conftest import FAST_METRICS, run_cli
from visphy_core.results.summary import STAGE_FIELDS

BASE = ("dataset=tiny", "model=static", *FAST_METRICS, "run.progress=false", "run.cache=false")
#: Fields that depend on when a row was made, not on what it is.
VOLATILE = set(STAGE_FIELDS)  # wall seconds of each stage: never equal across runs
#: Summary keys that name where and when, or that only a merged run has.
OWN = {"run_dir", "mlflow", "merged_from", "stage_seconds"}  # stage_seconds: wall times


def _rows(run_dir: Path) -> list[dict]:
    return [{k: v for k, v in json.loads(line).items() if k not in VOLATILE}
            for line in (run_dir / "results.jsonl").read_text().splitlines()]


def _json(path: Path) -> dict:
    return json.loads(path.read_text())


@pytest.fixture(scope="module")
def home(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("merge")


@pytest.fixture(scope="module")
def study(home) -> dict:
    """The two shards and the unsharded run as one study (a sweep over dataset.shard, the
    recipe's way of running shards; ``null`` is the whole run)."""
    run_cli("-m", *BASE, "dataset.shard=0/2,1/2,null", home=home)
    [path] = (home / "hydra").glob("multirun-*/study_summary.json")
    return _json(path)


def _run_of(study: dict, shard: str | None) -> Path:
    [job] = [j for j in study["jobs"]
             if yaml.safe_load((Path(j["run_dir"]) / "config.yaml").read_text())
             ["dataset"]["shard"] == shard]
    return Path(job["run_dir"])


@pytest.fixture(scope="module")
def shards(study) -> list[Path]:
    return [_run_of(study, "0/2"), _run_of(study, "1/2")]


@pytest.fixture(scope="module")
def full(study) -> Path:
    """The same run unsharded."""
    return _run_of(study, None)


@pytest.fixture(scope="module")
def merged(home, shards, full) -> tuple[Path, str]:
    """``merge`` through the CLI's entry point, in this process (a process start less)."""
    import io
    from contextlib import redirect_stdout

    from visphy_core.cli.main import main

    out = home / "runs" / "merged"
    printed = io.StringIO()
    with redirect_stdout(printed):
        assert main(["merge", *map(str, reversed(shards)), "-o", str(out)]) == 0
    return out, printed.getvalue()


def test_the_shards_split_the_scenes(shards, full):
    ids = [[r["scene_id"] for r in _rows(s)] for s in shards]
    assert [len(x) for x in ids] == [2, 1] and not set(ids[0]) & set(ids[1])
    assert sorted(ids[0] + ids[1]) == sorted(r["scene_id"] for r in _rows(full))


def test_the_merged_run_equals_the_unsharded_run(merged, full):
    out, stdout = merged
    assert "merged 2 shard(s) (0/2, 1/2): 3 scenes" in stdout
    assert _rows(out) == _rows(full)  # the same rows in the unsharded order
    volatile = list(VOLATILE)
    pd.testing.assert_frame_equal(
        pd.read_parquet(out / "results.parquet").drop(columns=volatile),
        pd.read_parquet(full / "results.parquet").drop(columns=volatile))
    mine, theirs = _json(out / "summary.json"), _json(full / "summary.json")
    assert {k: v for k, v in mine.items() if k not in OWN} == \
        {k: v for k, v in theirs.items() if k not in OWN}
    assert mine["metrics"]["psnr"]["n_model_success"] == 3
    manifest = _json(out / "manifest.json")
    assert manifest["scenes"] == _json(full / "manifest.json")["scenes"]
    assert manifest["config_hash"] == _json(full / "manifest.json")["config_hash"]
    assert [m["shard"] for m in manifest["merged_from"]] == ["0/2", "1/2"]
    assert yaml.safe_load((out / "config.yaml").read_text())["dataset"]["shard"] is None
    assert len((out / "calls.jsonl").read_text().splitlines()) == 3


def test_scene_folders_are_hard_links_to_the_shards(merged, shards):
    out, _ = merged
    for shard in shards:
        for row in _rows(shard):
            video = Path("scenes") / row["scene_id"] / "video.mp4"
            assert (out / video).stat().st_ino == (shard / video).stat().st_ino


def test_one_mlflow_run_is_the_shards_parent_and_the_studys_child(merged, study, shards):
    from mlflow.tracking import MlflowClient

    out, _ = merged
    info = _json(out / "summary.json")["mlflow"]
    client = MlflowClient(tracking_uri=info["tracking_uri"])
    run = client.get_run(info["run_id"])
    assert run.info.status == "FINISHED"
    assert run.data.tags["mlflow.parentRunId"] == study["parent"]["run_id"]
    assert run.data.tags["visphy.run_dir"] == str(out)
    assert run.data.metrics["n_scenes"] == 3
    assert run.data.metrics["psnr"] == pytest.approx(
        _json(out / "summary.json")["metrics"]["psnr"]["mean_model_success"])
    children = client.search_runs([info["experiment_id"]], filter_string=(
        f"tags.`mlflow.parentRunId` = '{info['run_id']}'"))
    assert {c.data.tags["visphy.run_dir"] for c in children} == {str(s) for s in shards}
    assert {c.info.run_id for c in children} == {
        j["mlflow_run_id"] for j in study["jobs"] if Path(j["run_dir"]) in shards}


# ------------------------------------------------------------------------------ refusals


def _copy(shard: Path, dest: Path, *, config: dict | None = None,
          summary: dict | None = None) -> Path:
    """A copy of a shard's run directory with some config or summary fields changed."""
    shutil.copytree(shard, dest)
    if config:
        cfg = yaml.safe_load((dest / "config.yaml").read_text())
        for key, value in config.items():
            node, *path = key.split(".")
            target = cfg[node]
            for part in path[:-1]:
                target = target[part]
            target[path[-1]] = value
        (dest / "config.yaml").write_text(yaml.safe_dump(cfg))
    if summary:
        data = _json(dest / "summary.json")
        data.update(summary)
        (dest / "summary.json").write_text(json.dumps(data))
    return dest


def _refused(*shards: Path, out: Path, extra: tuple[str, ...] = ()) -> str:
    import io
    from contextlib import redirect_stderr

    from visphy_core.cli.main import main

    existed = out.exists()
    err = io.StringIO()
    with redirect_stderr(err):
        assert main(["merge", *map(str, shards), "-o", str(out), *extra]) == 2
    lines = [line for line in err.getvalue().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: merge: ")
    assert existed or not out.exists()  # nothing written
    return lines[0]


def test_refusals(shards, merged, tmp_path):
    first, second = shards
    out = tmp_path / "out"
    other = _copy(second, tmp_path / "other", config={"model.name": "flow_extrapolate"})
    assert "are runs of different configs (model.name: static ≠ flow_extrapolate)" in \
        _refused(first, other, out=out)
    twice = _copy(first, tmp_path / "twice")
    assert "shard 0/2 is given twice" in _refused(first, twice, out=out)
    relabelled = _copy(first, tmp_path / "relabelled", config={"dataset.shard": "1/2"})
    assert "is in " in _refused(first, relabelled, out=out)  # one scene in two shards
    assert "shard(s) 1/2 missing" in _refused(first, out=out)
    stopped = _copy(second, tmp_path / "stopped", summary={"status": "interrupted"})
    assert "is interrupted: rerun its command" in _refused(first, stopped, out=out)
    assert "already exists" in _refused(first, second, out=merged[0])
    unsharded = _copy(first, tmp_path / "unsharded", config={"dataset.shard": None})
    assert "is not a shard" in _refused(unsharded, second, out=out)


def test_partial_merges_the_shards_named(shards, home):
    from visphy_core.execute.merge import check_shards, read_shard

    [one] = check_shards([read_shard(shards[1])], partial=True)
    assert one.index == (1, 2) and len(one.rows) == 1


def test_merge_study_merges_the_run_its_shards_belong_to(study, full, merged, tmp_path):
    """``--study``: the study's shards grouped by config (the unsharded job is no shard) and
    merged into OUT/<model>_<engine>_<hash8>; the newest merge adopts the shards' runs."""
    import io
    from contextlib import redirect_stdout

    from mlflow.tracking import MlflowClient

    from visphy_core.cli.main import main

    printed = io.StringIO()
    with redirect_stdout(printed):
        assert main(["merge", "--study", study["sweep_dir"], "-o", str(tmp_path / "all")]) == 0
    [out] = (tmp_path / "all").iterdir()
    chash = _json(full / "manifest.json")["config_hash"]
    assert out.name == f"static_threejs_{chash[:8]}"
    assert _rows(out) == _rows(full)
    info = _json(out / "summary.json")["mlflow"]
    client = MlflowClient(tracking_uri=info["tracking_uri"])
    adopted = client.search_runs([info["experiment_id"]], filter_string=(
        f"tags.`mlflow.parentRunId` = '{info['run_id']}'"))
    assert len(adopted) == 2
