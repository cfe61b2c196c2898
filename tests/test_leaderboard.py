"""`visphy leaderboard`: tie ranks from the paired bootstrap over shared scenes, the warning for
runs without shared scenes, reference rows kept apart, breakdowns, metric pages, media caps.

Runs are constructed (summary.json, manifest.json, config.yaml and results.jsonl written
directly): A is clearly above B; C differs from B by ±0.01 per scene (a tie); D ran other
scenes of the same dataset."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from visphy_core.infra.errors import UserError
from visphy_core.leaderboard import SiteOptions, build_site
from visphy_core.leaderboard.clips import cap_media
from visphy_core.leaderboard.references import read_references

REPO = Path(__file__).resolve().parents[1]
N = 20
DIFFICULTY = ("easy", "medium", "hard")


def write_run(root: Path, name: str, model: str, values: list[float], *, engine: str = "threejs",
              prefix: str = "vpb3-s0-2d") -> Path:
    """A finished run directory with ``physics_score`` and ``psnr`` per scene."""
    run = root / name
    run.mkdir(parents=True)
    rows = []
    for i, v in enumerate(values):
        rows.append({"scene_id": f"{prefix}-t{i % 5 + 1:03d}-v{i // 5:02d}",
                     "dim": "2d" if i % 4 else "3d", "difficulty": DIFFICULTY[i % 3],
                     "model_success": True, "system_success": True, "fallback": False,
                     "attempts": 1, "failure_class": None, "first_failure_class": None,
                     "score_physics_score": v, "score_psnr": 20 + 10 * v})
    (run / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    summary = {"status": "finished", "model": model, "engine": engine, "dataset": "mini",
               "n_scenes": len(rows), "model_success_rate": 1.0, "system_success_rate": 1.0,
               "metrics": {"physics_score": {"direction": "higher"},
                           "psnr": {"direction": "higher", "mean_model_success": 25.0}},
               "metric_info": {"psnr": {"family": "pixel", "range": [0, 60]}},
               "usage": {"all": {"cost_usd": 0.25, "input_tokens": 1000, "output_tokens": 200}},
               "stage_seconds": {"render_wall_s": {"total": 12.0},
                                 "scoring_wall_s": {"total": 30.0}}}
    (run / "summary.json").write_text(json.dumps(summary))
    (run / "manifest.json").write_text(json.dumps({"status": "finished",
                                                   "visphy_version": "0.1.0",
                                                   "started": "2026-11-29T01:02:03"}))
    config = {"model": {"name": model}, "engine": {"name": engine},
              "dataset": {"name": "mini"}, "paths": {"root": str(root)}}
    (run / "config.yaml").write_text(json.dumps(config))
    return run


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    low = [0.3 + 0.02 * (i % 5) for i in range(N)]
    write_run(root, "a", "strong", [v + 0.5 for v in low])
    write_run(root, "b", "weak", low)
    write_run(root, "c", "weak_twin", [v + (0.01 if i % 2 else -0.01) for i, v in
                                       enumerate(low)])
    write_run(root, "d", "elsewhere", low, prefix="other-s1-2d")
    return root


@pytest.fixture(scope="module")
def refs(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("refs") / "refs.yaml"
    path.write_text("- model: published-model\n  engine: threejs\n  dataset: mini\n"
                    "  physics_score: 0.95\n  ci_low: 0.9\n  ci_high: 0.99\n"
                    "  source: Example et al. 2026, table 2\n")
    return path


@pytest.fixture(scope="module")
def site(runs, refs, tmp_path_factory):
    out = tmp_path_factory.mktemp("site") / "site"
    built = build_site([runs], out, SiteOptions(references=read_references(refs),
                                                progress=False))
    return out, built


def _by_model(built):
    return {e.model: built.standings[e.slug] for e in built.entries}


def test_ties_share_a_rank_and_separable_rows_do_not(site):
    _, built = site
    ranks = _by_model(built)
    assert ranks["strong"].rank == 1
    assert ranks["weak"].rank == ranks["weak_twin"].rank == 2
    assert "weak_twin" in ranks["weak"].tied_with[0] and ranks["strong"].tied_with == []


def test_a_run_without_shared_scenes_is_not_ranked_and_is_named_in_a_warning(site):
    out, built = site
    assert _by_model(built)["elsewhere"].rank is None
    warned = [w for w in built.warnings if "elsewhere" in w and "share 0 scene" in w]
    assert len(warned) == 3
    assert "share 0 scene" in (out / "index.html").read_text()


def test_reference_rows_are_kept_apart_from_measured_rows(site):
    out, built = site
    html = (out / "index.html").read_text()
    measured = html.split('id="leaderboard"')[1].split("</table>")[0]
    reference = html.split('id="references"')[1].split("</table>")[0]
    assert "published-model" in reference and "Example et al. 2026" in reference
    assert "published-model" not in measured
    data = json.loads((out / "leaderboard.json").read_text())
    assert [r["model"] for r in data["references"]] == ["published-model"]
    assert all("published-model" not in row["label"] for row in data["rows"])
    assert all("published-model" not in t for row in data["rows"] for t in row["tied_with"])


def test_breakdowns_metric_pages_and_row_pages_are_written(site):
    out, built = site
    text = (out / "breakdowns.html").read_text()
    for table in ("by-difficulty", "by-template", "by-dim"):
        assert f'id="{table}"' in text
    assert "t001" in text and "3D" in text and "hard" in text
    assert (out / "metrics" / "psnr.html").is_file()
    assert "Validity" in (out / "metrics" / "headline.html").read_text()
    for e in built.entries:
        assert (out / "entries" / f"{e.slug}.html").is_file()
        assert (out / "runs" / e.slug / "index.html").is_file()


def test_the_site_ships_every_row_s_scores_as_visphy_export_writes_them(site):
    import pandas as pd

    from visphy_core.results.tidy import tidy_scores

    def plain(df):  # missing values as None whatever the dtype Parquet gave them
        return df.astype(object).where(df.notna(), None)

    out, built = site
    table = pd.read_parquet(out / "scores.parquet")
    assert sorted(table["row"].unique()) == sorted(e.label for e in built.entries)
    for e in built.entries:
        mine = table[table["row"] == e.label].drop(columns="row").reset_index(drop=True)
        assert len(mine) > 0
        pd.testing.assert_frame_equal(plain(mine), plain(tidy_scores(e.run.run_dir)))


def test_reference_file_errors_are_one_line(tmp_path):
    bad = tmp_path / "refs.csv"
    bad.write_text("model,physics_score\nx,0.5\n")
    with pytest.raises(UserError, match="missing source"):
        read_references(bad)
    bad.write_text("model,source,physics_score\nx,paper,high\n")
    with pytest.raises(UserError, match="not a number"):
        read_references(bad)


def test_the_media_cap_leaves_large_clips_out_and_says_so(tmp_path):
    report = tmp_path / "report"
    (report / "media").mkdir(parents=True)
    (report / "media" / "big.mp4").write_bytes(b"\0" * 2_000_000)
    (report / "media" / "small.mp4").write_bytes(b"\0" * 1000)
    (report / "index.html").write_text('<body><video src="media/big.mp4"></video>'
                                       '<video src="media/small.mp4"></video></body>')
    assert cap_media(report, max_clip_mb=1.0, max_report_mb=100.0) == ["media/big.mp4"]
    html = (report / "index.html").read_text()
    assert 'data-omitted="media/big.mp4"' in html and 'src="media/small.mp4"' in html
    assert "leaves out 1 clip" in html and not (report / "media" / "big.mp4").exists()


def test_the_command_writes_the_site_and_refuses_a_foreign_folder(runs, tmp_path):
    env_cmd = [sys.executable, "-m", "visphy_core", "leaderboard", str(runs / "a"),
               str(runs / "b"), "--no-reports", "--clips", "0"]
    ok = subprocess.run(env_cmd + ["-o", str(tmp_path / "s")], cwd=REPO, capture_output=True,
                        text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr
    assert "leaderboard:" in ok.stdout and (tmp_path / "s" / "index.html").is_file()
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    bad = subprocess.run(env_cmd + ["-o", str(foreign)], cwd=REPO, capture_output=True,
                         text=True, timeout=300)
    assert bad.returncode == 2 and "not a leaderboard site" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
