"""The run-directory format (`visphy_core.results`): what a run directory is, how rows are read
and written, and how a run that never wrote its summary is read."""

from __future__ import annotations

import io
import json

import pandas as pd
import pytest

from visphy_core.infra.errors import UserError
from visphy_core.results.layout import (
    CONFIG,
    MANIFEST,
    RESULTS_JSONL,
    RESULTS_PARQUET,
    SCENES,
    SUMMARY,
    is_finished_run,
    is_run_dir,
    run_status,
)
from visphy_core.results.load import load_run
from visphy_core.results.row import SceneResult
from visphy_core.results.rows import jsonl_line, parquet_bytes, read_results, write_results


def row(scene_id: str, psnr: float | None, ok: bool = True, **kw) -> SceneResult:
    return SceneResult(scene_id=scene_id, dim="2d", difficulty="easy", model_success=ok,
                       system_success=True, attempts=1, scores={"psnr": psnr}, **kw)


def test_what_makes_a_folder_a_run(tmp_path):
    assert not is_run_dir(tmp_path / "missing")
    (tmp_path / "file").write_text("x")
    assert not is_run_dir(tmp_path / "file")
    hydra = tmp_path / ".hydra"   # Hydra writes a config.yaml in every job's .hydra/
    hydra.mkdir()
    (hydra / CONFIG).write_text("a: 1\n")
    assert not is_run_dir(hydra)
    (hydra / SCENES).mkdir()      # a config beside scenes/ is a run that wrote nothing else yet
    assert is_run_dir(hydra) and not is_finished_run(hydra)
    killed = tmp_path / "killed"
    killed.mkdir()
    (killed / MANIFEST).write_text('{"status": "running"}')
    assert is_run_dir(killed) and not is_finished_run(killed)
    for status in ("interrupted", "failed", "cost_cap"):  # closed, with a summary, incomplete
        (killed / MANIFEST).write_text(json.dumps({"status": status}))
        (killed / SUMMARY).write_text(json.dumps({"status": status}))
        assert not is_finished_run(killed) and run_status(killed) == status
    (killed / MANIFEST).write_text('{"status": "finished"}')
    assert is_finished_run(killed)


def test_rows_first_per_scene_and_unreadable_lines_counted(tmp_path):
    lines = [jsonl_line(row("a", 1.0)), jsonl_line(row("b", 2.0)),
             jsonl_line(row("a", 9.0)),        # a resumed run's duplicate: the first wins
             "not json\n", '{"no_scene_id": 1}\n', "\n",
             jsonl_line(row("c", None))[:-20]]  # the half-written last line of a killed run
    (tmp_path / RESULTS_JSONL).write_text("".join(lines))
    results, skipped = read_results(tmp_path)
    assert [(r.scene_id, r.scores["psnr"]) for r in results] == [("a", 1.0), ("b", 2.0)]
    assert skipped == 3


def test_written_rows_read_back_from_either_file(tmp_path):
    rows = [row("a", 1.5, flags=["static_output"]), row("b", None, ok=False,
                                                       failure_class="no_code")]
    write_results(tmp_path, rows)
    from_jsonl, _ = read_results(tmp_path)
    (tmp_path / RESULTS_JSONL).unlink()
    from_parquet, _ = read_results(tmp_path)
    for got in (from_jsonl, from_parquet):
        assert [r.row() for r in got] == [r.row() for r in rows]
    # the Parquet bytes are what pandas writes to a path (a run's file is unchanged by this)
    frame = pd.DataFrame([r.row() for r in rows])
    buffer = io.BytesIO()
    frame.to_parquet(buffer, index=False)
    assert parquet_bytes(rows) == buffer.getvalue()
    assert (tmp_path / RESULTS_PARQUET).read_bytes() == buffer.getvalue()


def test_a_killed_run_is_read_with_a_recomputed_summary(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / MANIFEST).write_text(json.dumps({
        "scenes": ["b", "a", "c"], "status": "running",
        "metrics": [{"name": "psnr", "direction": "higher"}]}))
    (run / RESULTS_JSONL).write_text(jsonl_line(row("a", 20.0)) + jsonl_line(row("b", 30.0))
                                     + '{"scene_id": "c", "dim"')
    data = load_run(run)
    assert [r.scene_id for r in data.results] == ["b", "a"]   # the manifest's order
    assert data.pending == ["c"] and data.skipped_lines == 1
    assert data.summary_source.startswith("recomputed")
    assert data.summary["n_scenes"] == 2 and data.summary["model_success"] == 2
    assert data.summary["metrics"]["psnr"]["mean_model_success"] == 25.0
    assert data.table["scene_id"].tolist() == ["b", "a"]
    with pytest.raises(UserError, match="not a finished run"):
        load_run(run, finished=True)
    with pytest.raises(UserError, match="not a visphy run directory"):
        load_run(tmp_path)


def test_analyse_leaves_out_unfinished_runs_and_says_so(tmp_path, capsys):
    from visphy_core.analysis.load import find_runs

    for name, status in (("done", "finished"), ("stopped", "interrupted"),
                         ("capped", "cost_cap")):
        run_dir = tmp_path / "runs" / name
        run_dir.mkdir(parents=True)
        (run_dir / MANIFEST).write_text(json.dumps({"status": status}))
        (run_dir / SUMMARY).write_text(json.dumps({"status": status}))
        (run_dir / RESULTS_JSONL).write_text("")
    assert find_runs(tmp_path / "runs") == [(tmp_path / "runs" / "done").resolve()]
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("left out 2 unfinished run(s) under ")
    assert "capped (cost_cap), stopped (interrupted)" in line
    with pytest.raises(UserError, match="the run is interrupted, not finished: rerun its"):
        find_runs(tmp_path / "runs" / "stopped")
    with pytest.raises(UserError, match="the run is interrupted, not finished"):
        load_run(tmp_path / "runs" / "stopped", finished=True)
