"""The analysis package on small synthetic runs whose every number can be worked out by hand:
Krippendorff's alpha (a hand-computed example and Krippendorff's own worked one), the paired
bootstrap (deterministic, vectorised = a plain loop, exact on a constant shift), Spearman
matrices, the leaderboard's two success views with counts, the failure, difficulty, parameter
and retry tables, labels, loading errors, the exporters and the study's files.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from visphy_core.analysis import breakdown, correlation, figures, leaderboard, params, retry
from visphy_core.analysis.agreement import krippendorff_alpha
from visphy_core.analysis.bootstrap import bootstrap_table, paired_bootstrap, resample_indices
from visphy_core.analysis.export import to_latex, to_markdown
from visphy_core.analysis.human import read_ratings, summarise_ratings
from visphy_core.analysis.load import find_runs, label_runs, load_run, load_runs
from visphy_core.analysis.study import STUDIES, analyse
from visphy_core.api.errors import UserError
from visphy_core.results.load import RunData
from visphy_core.results.row import SceneResult

NAN = math.nan
DIRECTIONS = {"psnr": "higher", "flow_epe_dis": "lower", "param_gravity_err": "lower",
              "param_speed_err": "lower", "judge_a": "higher", "judge_b": "higher",
              "physics_score": "higher"}


def make_run(tmp: Path | None, name: str, rows: list[dict], *, model: str = "m",
             engine: str = "threejs", retry_on: bool = True, detection: bool = True,
             ratings: list[dict] | None = None) -> RunData:
    """A RunData from scene rows (``scores``: {column: value}); written to ``tmp/name`` as a
    real run directory when ``tmp`` is given."""
    base = {"dim": "2d", "difficulty": "easy", "model_success": True, "system_success": True,
            "fallback": False, "attempts": 1, "failure_class": None,
            "first_failure_class": None}
    records = []
    for r in rows:
        rec = {**base, **{k: v for k, v in r.items() if k != "scores"}}
        rec.update({f"score_{k}": v for k, v in r.get("scores", {}).items()})
        records.append(rec)
    df = pd.DataFrame(records)
    cols = sorted({k for r in rows for k in r.get("scores", {})})
    summary = {"status": "finished", "model": model, "engine": engine,
               "metrics": {c: {"direction": DIRECTIONS[c], "unavailable": None} for c in cols}}
    config = {"model": {"name": model}, "engine": {"name": engine},
              "dataset": {"name": "mini", "limit": None, "scenes": None, "seed": 0},
              "run": {"retry": retry_on, "progress": False},
              "prompt": {"detection": detection}, "paths": {"root": str(tmp)}}
    run_dir = Path(tmp or "/nonexistent") / name
    if tmp is not None:
        run_dir.mkdir(parents=True)
        (run_dir / "summary.json").write_text(json.dumps(summary))
        (run_dir / "manifest.json").write_text("{}")
        (run_dir / "config.yaml").write_text(json.dumps(config))   # JSON is YAML
        df.to_parquet(run_dir / "results.parquet", index=False)
        if ratings:
            (run_dir / "human_ratings.jsonl").write_text(
                "".join(json.dumps(x) + "\n" for x in ratings))
        return load_run(run_dir)
    return RunData(run_dir=run_dir, config=config, summary=summary, manifest={},
                   results=[SceneResult.from_row(r) for r in records],
                   ratings=read_ratings(None))


def scenes(values: dict[str, list[float]], **extra) -> list[dict]:
    n = len(next(iter(values.values())))
    return [{"scene_id": f"s{i}", **{k: (v[i] if isinstance(v, list) else v)
                                     for k, v in extra.items()},
             "scores": {c: v[i] for c, v in values.items()}} for i in range(n)]


# ----------------------------------------------------------------------------- agreement


def test_krippendorff_alpha_hand_computed_example():
    """Two raters, three items: (1,1), (2,3), (3,3). Coincidences: o11=2, o23=o32=1, o33=2;
    n1=2, n2=1, n3=3, n=6. Ordinal δ²: (1,2) (3-1.5)²=2.25, (2,3) (4-2)²=4, (1,3) (6-2.5)²=12.25.
    D_o ∝ 2·4 = 8, D_e ∝ 2·(2·1·2.25 + 1·3·4 + 2·3·12.25)/(n-1) = 36: α = 1 - 8/36 = 7/9."""
    assert krippendorff_alpha([[1, 2, 3], [1, 3, 3]], "ordinal") == pytest.approx(7 / 9)
    # nominal: δ² = 1 off the diagonal: D_o ∝ 2, D_e ∝ 2·(2+3+6)/5 = 4.4
    assert krippendorff_alpha([[1, 2, 3], [1, 3, 3]], "nominal") == pytest.approx(1 - 2 / 4.4)


def test_krippendorff_alpha_matches_krippendorffs_worked_example():
    """Krippendorff (2011), 'Computing Krippendorff's Alpha-Reliability': 4 coders, 12 units,
    missing values; ordinal α = 0.815, nominal 0.743, interval 0.849."""
    data = [[1, 2, 3, 3, 2, 1, 4, 1, 2, NAN, NAN, NAN],
            [1, 2, 3, 3, 2, 2, 4, 1, 2, 5, NAN, 3],
            [NAN, 3, 3, 3, 2, 3, 4, 2, 2, 5, 1, NAN],
            [1, 2, 3, 3, 2, 4, 4, 1, 2, 5, 1, NAN]]
    assert round(krippendorff_alpha(data, "ordinal"), 3) == 0.815
    assert round(krippendorff_alpha(data, "nominal"), 3) == 0.743
    assert round(krippendorff_alpha(data, "interval"), 3) == 0.849
    assert krippendorff_alpha([[1, 2, 5], [1, 2, 5]]) == 1.0
    assert math.isnan(krippendorff_alpha([[1, NAN], [NAN, 2]]))      # nothing pairable
    assert math.isnan(krippendorff_alpha([[3, 3], [3, 3]]))          # no variation at all


def test_ratings_last_line_wins_and_bad_lines_are_skipped(tmp_path):
    path = tmp_path / "human_ratings.jsonl"
    lines = [{"scene_id": "s0", "rater": "ann", "rating": 2, "item": "i0", "ts": "t1"},
             {"scene_id": "s0", "rater": "ann", "rating": 4, "item": "i0", "ts": "t2"},
             {"scene_id": "s0", "rater": "bob", "rating": 5, "item": "i0", "ts": "t1"},
             {"scene_id": "s1", "rater": "bob", "rating": 1, "item": "i1", "ts": "t1"},
             {"scene_id": "s1", "rater": "bob", "rating": 6, "item": "i1", "ts": "t3"},
             {"scene_id": "s1", "rater": "bob", "rating": True, "item": "i1", "ts": "t3"}]
    path.write_text("".join(json.dumps(x) + "\n" for x in lines) + '{"scene_id": "s1", "ra')
    ratings = read_ratings(path)
    assert ratings.attrs["skipped"] == 3
    assert sorted(zip(ratings["rater"], ratings["item"], ratings["rating"])) == [
        ("ann", "i0", 4), ("bob", "i0", 5), ("bob", "i1", 1)]
    s = summarise_ratings(ratings)
    # scene means: s0 (4+5)/2 = 4.5, s1 1 -> mean over scenes 2.75
    assert (s["mean"], s["n"], s["raters"], s["scenes"]) == (2.75, 3, 2, 2)
    assert s["alpha"] == pytest.approx(krippendorff_alpha([[4, NAN], [5, 1]]), nan_ok=True)


# ----------------------------------------------------------------------------- bootstrap


def test_paired_bootstrap_is_deterministic_vectorised_and_exact_on_a_shift():
    rng = np.random.default_rng(3)
    b = rng.normal(size=40)
    shifted = paired_bootstrap(b + 1.5, b)
    assert (shifted.diff, shifted.ci_low, shifted.ci_high) == pytest.approx((1.5, 1.5, 1.5))
    assert shifted.p == pytest.approx(2 / 10_001)
    a = b + rng.normal(0.3, 1.0, size=40)
    first, again = paired_bootstrap(a, b, 2000, seed=7), paired_bootstrap(a, b, 2000, seed=7)
    assert first == again
    idx = resample_indices(40, 2000, 7)
    loop = np.array([np.mean(a[row] - b[row]) for row in idx])
    assert (first.ci_low, first.ci_high) == pytest.approx(tuple(np.quantile(loop, [.025, .975])))
    below = (np.sum(loop <= 0) + 1) / 2001
    above = (np.sum(loop >= 0) + 1) / 2001
    assert first.p == pytest.approx(min(1, 2 * min(below, above)))
    # the interval is about mean ± 1.96 sd/√n for a sample this size
    half = 1.96 * np.std(a - b, ddof=1) / np.sqrt(40)
    assert (first.ci_high - first.ci_low) / 2 == pytest.approx(half, rel=0.2)
    null = paired_bootstrap(b + rng.normal(0, 0.01, 40) * 0, b)
    assert null.p == 1.0 and null.ci_low == null.ci_high == 0.0
    assert paired_bootstrap(np.array([]), np.array([])).n == 0


def test_bootstrap_table_uses_common_scenes_and_the_metric_direction():
    a = make_run(None, "a", scenes({"psnr": [30, 31, 32, 33, 34], "flow_epe_dis": [1, 1, 1, 1, 1]}))
    b = make_run(None, "b", scenes({"psnr": [20, 21, 22, 23, 99], "flow_epe_dis": [2, 3, 2, 3, 9]}))
    b.table.loc[4, "model_success"] = False       # s4: not a model success of b
    table = bootstrap_table([a, b], ["A", "B"], ["psnr", "flow_epe_dis"], resamples=1000)
    psnr = table[table["metric"] == "psnr ↑"].iloc[0]
    assert psnr["n common"] == 4 and psnr["A − B"] == pytest.approx(10.0)
    assert psnr["better"] == "A"
    flow = table[table["metric"] == "flow_epe_dis ↓"].iloc[0]
    assert flow["A − B"] == pytest.approx(-1.5) and flow["better"] == "A"   # lower is better
    fb = bootstrap_table([a, b], ["A", "B"], ["psnr"], view="with_fallbacks", resamples=1000)
    assert fb.iloc[0]["n common"] == 5


# ----------------------------------------------------------------------------- correlation


def test_spearman_matrix_mean_offdiagonal_and_p_values():
    x = [0.1, 0.5, 0.3, 0.9, 0.7, 0.2]
    a = make_run(None, "a", scenes({"flow_epe_dis": x}))
    b = make_run(None, "b", scenes({"flow_epe_dis": [v ** 3 + 1 for v in x]}))   # same order
    c = make_run(None, "c", scenes({"flow_epe_dis": [-v for v in x]}))           # reversed
    long = correlation.spearman_long([a, b, c], ["A", "B", "C"], ["flow_epe_dis"])
    rho = {(r["A"], r["B"]): r["ρ"] for r in long.to_dict("records")}
    assert rho == pytest.approx({("A", "B"): 1.0, ("A", "C"): -1.0, ("B", "C"): -1.0})
    matrix = correlation.spearman_matrix(long, ["A", "B", "C"], "flow_epe_dis").set_index("run")
    assert matrix.loc["A", "A"] == 1 and matrix.loc["C", "B"] == -1
    mean = correlation.mean_offdiagonal(long).iloc[0]
    assert mean["mean ρ"] == pytest.approx(-1 / 3) and mean["pairs"] == 3
    assert mean["paper ρ"] == 0.84 and mean["paper metric"] == "raft_epe"
    y = [3, 1, 2, 5, 4, 6]
    assert correlation.spearman(x, y)[:2] == pytest.approx(tuple(stats.spearmanr(x, y)))
    assert correlation.pearson(x, y)[:2] == pytest.approx(tuple(stats.pearsonr(x, y)))
    assert math.isnan(correlation.spearman([1, 2], [2, 1])[0])          # two points: undefined
    assert math.isnan(correlation.spearman([1, 2, 3], [5, 5, 5])[0])    # constant side


def test_judge_agreement_pools_runs_and_adds_humans():
    ratings = [{"scene_id": f"s{i}", "rater": r, "rating": v, "item": f"i{i}", "ts": ""}
               for i, (v1, v2) in enumerate([(1, 2), (3, 3), (5, 4), (2, 2)])
               for r, v in (("ann", v1), ("bob", v2))]
    a = make_run(None, "a", scenes({"judge_a": [1, 4, 8, 3], "judge_b": [2, 5, 7, 1]}))
    a.ratings = read_ratings(None)
    a.ratings = pd.DataFrame(ratings)
    b = make_run(None, "b", scenes({"judge_a": [9, 2], "judge_b": [8, 4]}))
    table = correlation.judge_agreement([a, b], ["judge_a", "judge_b"]).set_index(["A", "B"])
    ja, jb = [1, 4, 8, 3, 9, 2], [2, 5, 7, 1, 8, 4]
    row = table.loc[("judge_a", "judge_b")]
    assert row["n"] == 6
    assert row["pearson r"] == pytest.approx(stats.pearsonr(ja, jb).statistic)
    assert row["spearman ρ"] == pytest.approx(stats.spearmanr(ja, jb).statistic)
    human = table.loc[("judge_a", "human")]
    assert human["n"] == 4       # only run a was rated
    assert human["spearman ρ"] == pytest.approx(
        stats.spearmanr([1, 4, 8, 3], [1.5, 3, 4.5, 2]).statistic)


# ----------------------------------------------------------------------------- tables


def test_leaderboard_both_views_with_counts_and_human(tmp_path):
    rows = scenes({"psnr": [40.0, 30.0, 10.0, None]},
                  model_success=[True, True, False, False],
                  fallback=[False, False, True, False],
                  system_success=[True, True, True, False],
                  failure_class=[None, None, "syntax_error", "infra_error"])
    ratings = [{"scene_id": "s0", "rater": "ann", "rating": 4, "item": "i0", "ts": ""},
               {"scene_id": "s0", "rater": "bob", "rating": 5, "item": "i0", "ts": ""},
               {"scene_id": "s1", "rater": "ann", "rating": 2, "item": "i1", "ts": ""}]
    run = make_run(tmp_path, "r", rows, ratings=ratings)
    table = leaderboard.leaderboard([run], ["R"], ["psnr"]).iloc[0]
    assert table["psnr ↑"] == 35.0 and table["psnr n"] == 2
    assert table["psnr ↑ +fb"] == pytest.approx(80 / 3) and table["psnr n +fb"] == 3
    assert (table["n_scenes"], table["n_evaluable"], table["fallbacks"]) == (4, 3, 1)
    assert table["model success rate"] == 0.5 and table["system success rate"] == 0.75
    assert table["human ↑"] == pytest.approx((4.5 + 2) / 2) and table["human n"] == 3
    assert table["human raters"] == 2


def test_failure_and_difficulty_tables():
    rows = scenes({"psnr": [40, 30, 20, 10, 5]},
                  model_success=[True, True, False, False, False],
                  difficulty=["easy", "hard", "hard", "medium", "easy"],
                  dim=["2d", "2d", "3d", "3d", "3d"], attempts=[1, 2, 2, 2, 1],
                  failure_class=[None, None, "syntax_error", "timeout", "data_error"])
    run = make_run(None, "r", rows)
    fail = breakdown.failure_table([run], ["R"]).iloc[0]
    assert (fail["syntax_error"], fail["timeout"], fail["data_error (not evaluable)"]) == (1, 1, 1)
    assert (fail["n_evaluable"], fail["model success"], fail["repaired"]) == (4, 2, 1)
    assert "runtime_error" not in fail.index and fail["infra_error (not evaluable)"] == 0
    diff = breakdown.difficulty_table([run], ["R"], ["psnr"]).set_index(["by", "group"])
    assert list(diff.index) == [("difficulty", "easy"), ("difficulty", "medium"),
                                ("difficulty", "hard"), ("dim", "2D"), ("dim", "3D")]
    assert diff.loc[("difficulty", "hard"), "psnr ↑"] == 30 and \
        diff.loc[("difficulty", "hard"), "psnr n"] == 1
    assert diff.loc[("difficulty", "hard"), "model success rate"] == 0.5
    assert diff.loc[("dim", "3D"), "psnr n"] == 0


def test_param_and_retry_tables():
    rows = scenes({"param_gravity_err": [0.5, 1.5, None], "param_speed_err": [2.0, None, None]},
                  model_success=[True, True, True], attempts=[1, 2, 2],
                  first_failure_class=[None, "runtime_error", "no_code"])
    run = make_run(None, "r", rows)
    run.table.loc[2, ["model_success", "failure_class"]] = [False, "no_code"]
    p = params.param_table([run], ["R"], ["param_gravity_err", "param_speed_err", "psnr"])
    assert p.iloc[0]["gravity MAE ↓ [m/s²]"] == 1.0 and p.iloc[0]["gravity n"] == 2
    assert p.iloc[0]["initial speed n"] == 1 and p.iloc[1]["run"] == params.PAPER_LABEL
    assert p.iloc[1]["initial speed MAE ↓ [m/s]"] == 2.07
    r = retry.retry_table([run], ["R"]).set_index("run")
    assert (r.loc["R", "first attempt"], r.loc["R", "after retry"], r.loc["R", "rescued"]) == \
        (1, 2, 1)
    assert r.loc["R", "success (first)"] == pytest.approx(1 / 3)
    assert r.loc["paper: p5 (reference)", "success (retry)"] == 0.979


# ----------------------------------------------------------------------------- loading, labels


def test_labels_say_what_differs(tmp_path):
    rows = scenes({"psnr": [1.0]})
    on = make_run(tmp_path, "on", rows, retry_on=True)
    off = make_run(tmp_path, "off", rows, retry_on=False)
    other = make_run(tmp_path, "other", rows, model="static")
    same = make_run(tmp_path, "same", rows, retry_on=False)
    assert label_runs([on, off, other]) == ["m/threejs run.retry=true",
                                            "m/threejs run.retry=false", "static/threejs"]
    labels = label_runs([off, same])
    assert labels == ["m/threejs [off]", "m/threejs [same]"]


def test_find_and_load_runs(tmp_path):
    rows = scenes({"psnr": [1.0, 2.0]})
    make_run(tmp_path / "sweep" / "jobs" / "0", "run_a", rows)
    make_run(tmp_path / "sweep" / "jobs" / "1", "run_b", rows, model="static")
    found = find_runs(tmp_path / "sweep")
    assert [p.name for p in found] == ["run_a", "run_b"]
    assert find_runs(found[0], tmp_path / "sweep") == found       # each once
    runs = load_runs([tmp_path / "sweep"])
    assert [r.label for r in runs] == ["m/threejs", "static/threejs"]
    # a study's sweep folder: its job records point at runs kept elsewhere (paths.runs_dir)
    from visphy_core.results.study_records import write_job

    elsewhere = make_run(tmp_path / "runs", "run_c", rows, model="flow").run_dir
    write_job(tmp_path / "study" / "jobs" / "0", num=0, status="completed",
              run_dir=str(elsewhere))
    write_job(tmp_path / "study" / "jobs" / "1", num=1, status="failed", run_dir=None)
    assert find_runs(tmp_path / "study") == [elsewhere]
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="no finished run directory here"):
        find_runs(tmp_path / "empty")
    with pytest.raises(UserError, match="no such file"):
        find_runs(tmp_path / "missing")
    with pytest.raises(UserError, match="not a visphy run directory"):
        load_run(tmp_path / "empty")
    # the JSON lines when the Parquet is gone, a torn last line skipped, the first row of a
    # scene kept (as a resumed run keeps it), an older row's missing fields defaulted
    run_dir = found[0]
    (run_dir / "results.parquet").unlink()
    (run_dir / "results.jsonl").write_text(
        json.dumps({"scene_id": "s0", "score_psnr": 1.0, "model_success": True}) + "\n"
        + json.dumps({"scene_id": "s0", "score_psnr": 3.0, "model_success": True}) + "\n"
        + '{"scene_id": "s1", "sco')
    df = load_run(run_dir).table
    assert list(df["scene_id"]) == ["s0"] and df["score_psnr"].tolist() == [1.0]
    assert df["fallback"].tolist() == [False] and df["first_failure_class"].isna().all()
    assert analyse([load_run(run_dir)], tmp_path / "old").tables["leaderboard"].loc[
        0, "psnr ↑"] == 1.0


# ----------------------------------------------------------------------------- export, figures


def test_markdown_and_latex_export():
    df = pd.DataFrame({"run": ["a_b|c"], "psnr ↑": [31.23456], "n": [3], "p": [NAN]})
    md = to_markdown(df)
    assert md.splitlines()[0] == "| run | psnr ↑ | n | p |"
    assert md.splitlines()[1] == "|:---|---:|---:|---:|"
    assert md.splitlines()[2] == "| a_b\\|c | 31.23 | 3 | — |"
    tex = to_latex(df, caption="x_y 95%")
    assert r"psnr $\uparrow$" in tex and r"a\_b|c & 31.23 & 3 & --- \\" in tex
    assert r"\caption{x\_y 95\%}" in tex and r"\begin{tabular}{lrrr}" in tex


def test_radar_scales_each_metric_with_its_direction():
    a = make_run(None, "a", scenes({"psnr": [30, 30], "flow_epe_dis": [1, 1]}))
    b = make_run(None, "b", scenes({"psnr": [20, 20], "flow_epe_dis": [3, 3]}))
    c = make_run(None, "c", scenes({"psnr": [25, 25], "flow_epe_dis": [2, 2]}))
    t = figures.radar_table([a, b, c], ["A", "B", "C"], ["psnr", "flow_epe_dis"])
    assert figures.RADAR_FLOOR == 0.2       # the worst run sits at 0.2, not at the centre
    assert t["psnr ↑"].tolist() == pytest.approx([1.0, 0.2, 0.6])
    assert t["flow_epe_dis ↓"].tolist() == pytest.approx([1.0, 0.2, 0.6])  # lowest error best


def _polygon_area(radii: np.ndarray, angles: np.ndarray) -> float:
    x, y = radii * np.cos(angles), radii * np.sin(angles)
    return 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))


@pytest.mark.parametrize("n_runs", [2, 3])
def test_radar_draws_every_run_as_a_visible_distinct_polygon(tmp_path, monkeypatch, n_runs):
    """The worst run (worst on every metric) is still a polygon of non-zero area, and each run
    has its own marker and a legend entry."""
    cols = ["psnr", "judge_a", "flow_epe_dis", "param_gravity_err"]
    runs = [make_run(None, f"r{i}", scenes({"psnr": [30 - 5 * i] * 2, "judge_a": [9 - 3 * i] * 2,
                                             "flow_epe_dis": [1 + i] * 2,
                                             "param_gravity_err": [0.5 + i] * 2}))
            for i in range(n_runs)]
    labels = [f"run {i}" for i in range(n_runs)]
    table = figures.radar_table(runs, labels, cols)
    drawn = {}
    real_save = figures.save

    def capture(fig, out_dir, name, tight_box=False):
        ax = fig.axes[0]
        drawn["lines"] = [(np.asarray(ln.get_xdata()), np.asarray(ln.get_ydata()),
                           ln.get_marker(), ln.get_label()) for ln in ax.get_lines()]
        drawn["legend"] = [t.get_text() for t in ax.get_legend().get_texts()]
        return real_save(fig, out_dir, name, tight_box)

    monkeypatch.setattr(figures, "save", capture)
    assert [p.suffix for p in figures.radar(table, tmp_path)] == [".png", ".svg"]
    lines = drawn["lines"]
    assert len(lines) == n_runs and drawn["legend"] == labels
    areas = [_polygon_area(r[:-1], a[:-1]) for a, r, _, _ in lines]
    assert min(areas) > 0.05                      # the worst run is not a point at the centre
    assert min(r.min() for _, r, _, _ in lines) == pytest.approx(figures.RADAR_FLOOR)
    assert len({m for _, _, m, _ in lines}) == n_runs          # each run its own marker
    assert len({tuple(np.round(r, 6)) for _, r, _, _ in lines}) == n_runs


# ----------------------------------------------------------------------------- analyse


def test_analyse_writes_every_table_and_figure(tmp_path):
    rng = np.random.default_rng(0)
    base = rng.uniform(10, 40, 8)
    runs = [make_run(tmp_path / "runs", name, scenes(
        {"psnr": list(base + shift + rng.normal(0, 1, 8)),
         "flow_epe_dis": list(rng.uniform(0, 1, 8)),
         "judge_a": list(rng.integers(1, 11, 8).astype(float)),
         "judge_b": list(rng.integers(1, 11, 8).astype(float))}), model=name)
        for name, shift in (("good", 5.0), ("bad", -5.0), ("mid", 0.0))]
    out = analyse(runs, tmp_path / "out")
    assert {"runs", "leaderboard", "leaderboard_all", "failures", "difficulty", "bootstrap",
            "spearman", "spearman_mean", "spearman_psnr", "judges", "radar"} <= set(out.tables)
    for name in out.tables:
        for ext in ("csv", "md", "tex"):
            assert (tmp_path / "out" / f"{name}.{ext}").is_file(), (name, ext)
    assert set(out.figures) == {"boxplot_psnr", "boxplot_flow_epe_dis", "boxplot_judge_a",
                                "boxplot_judge_b", "radar"}
    for paths in out.figures.values():
        assert [p.suffix for p in paths] == [".png", ".svg"]
        assert paths[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert b"<svg" in paths[1].read_bytes()[:2000]
    index = json.loads((tmp_path / "out" / "analysis.json").read_text())
    assert set(index["tables"]) == set(out.tables)
    assert index["metrics"] == ["psnr", "flow_epe_dis", "judge_a", "judge_b"]
    assert out.markdown == (tmp_path / "out" / "analysis.md").read_text()
    assert "## Mean off-diagonal Spearman ρ per metric" in out.markdown
    csv = pd.read_csv(tmp_path / "out" / "leaderboard_all.csv")
    assert csv["psnr ↑"].tolist() == pytest.approx(out.tables["leaderboard"]["psnr ↑"].tolist())
    boot = out.tables["bootstrap"]
    good_bad = boot[(boot["metric"] == "psnr ↑") & (boot["A"] == "good/threejs")
                    & (boot["B"] == "bad/threejs")].iloc[0]
    assert good_bad["better"] == "good/threejs" and good_bad["CI low"] > 0
    # a study keeps to what it is about
    retry_only = analyse(runs, tmp_path / "retry", study="retry_ablation")
    assert "retry" in retry_only.tables and "spearman" not in retry_only.tables
    cross = analyse(runs, tmp_path / "cross", study="cross_engine", metrics=["psnr"])
    assert "spearman_psnr" in cross.tables and "spearman_flow_epe_dis" not in cross.tables
    assert "judges" not in cross.tables
    analyse(runs[:1], tmp_path / "odd", study="smoke")
    assert any("not one of" in n for n in json.loads(
        (tmp_path / "odd" / "analysis.json").read_text())["notes"])
    with pytest.raises(UserError, match="unknown metric column"):
        analyse(runs, tmp_path / "bad", metrics=["psnr", "nope"])
    assert set(STUDIES) == {"leaderboard", "cross_engine", "judge_replacement", "no_detection",
                            "forecast_only", "retry_ablation", "param_recovery", "baselines"}


# ----------------------------------------------------------------------------- small samples
def _two_runs(tmp: Path | None, n: int, seed: int = 0) -> list[RunData]:
    rng = np.random.default_rng(seed)
    base = rng.uniform(10, 40, n)
    return [make_run(tmp / name if tmp else None, name, scenes(
        {"psnr": list(base + shift + rng.normal(0, 1, n)),
         "judge_a": list(rng.integers(1, 11, n).astype(float)),
         "judge_b": list(rng.integers(1, 11, n).astype(float))}), model=name)
        for name, shift in (("good", 5.0), ("bad", -5.0))]


def test_small_sample_marks_the_numbers_over_fewer_than_ten_scenes():
    from visphy_core.analysis import small_sample

    assert small_sample.MIN_SCENES == 10
    assert [small_sample.small(n) for n in (0, 1, 9, 10, 40, NAN, None)] == [
        False, True, True, False, False, False, False]
    few, many = _two_runs(None, 6), _two_runs(None, 12)
    for runs, flagged in ((few, True), (many, False)):
        long = correlation.spearman_long(runs, ["A", "B"], ["psnr"])
        tables = {"spearman": long, "spearman_mean": correlation.mean_offdiagonal(long),
                  "spearman_psnr": correlation.spearman_matrix(long, ["A", "B"], "psnr"),
                  "bootstrap": bootstrap_table(runs, ["A", "B"], ["psnr"], resamples=200),
                  "judges": correlation.judge_agreement(runs[:1], ["judge_a", "judge_b"])}
        marks = small_sample.marks(tables)
        if not flagged:
            assert marks == {}
            continue
        assert set(marks) == set(tables)
        assert marks["spearman"].iloc[0].to_dict() == {
            "metric": False, "A": False, "B": False, "n": False, "ρ": True, "p": True}
        assert marks["spearman_mean"]["mean ρ"].tolist() == [True]
        # the matrix: both off-diagonal cells, never the diagonal or the labels
        assert marks["spearman_psnr"].to_numpy().tolist() == [[False, False, True],
                                                               [False, True, False]]
        boot = marks["bootstrap"].iloc[0]
        assert boot[["A − B", "CI low", "CI high", "p", "better"]].all()
        assert not boot[["n common", "mean A", "mean B"]].any()
        assert marks["judges"].iloc[0][["pearson r", "spearman ρ"]].all()
    # a coefficient that is not there (n < 3: a dash) carries no warning
    two = _two_runs(None, 2)
    long = correlation.spearman_long(two, ["A", "B"], ["psnr"])
    assert small_sample.marks({"spearman": long}) == {}


def test_analyse_warns_beside_small_sample_numbers_in_every_output(tmp_path):
    import io

    from rich.console import Console

    from visphy_core.analysis.printing import print_study

    few = analyse(_two_runs(tmp_path / "few", 6), tmp_path / "out", resamples=200)
    out = tmp_path / "out"
    md = (out / "spearman_psnr.md").read_text()
    assert md.splitlines()[2].endswith(" ⚠ |") and "fewer than 10 common scenes" in md
    boot_md = (out / "bootstrap.md").read_text().splitlines()
    psnr_row = next(line for line in boot_md if line.startswith("| psnr ↑"))
    assert psnr_row.count(" ⚠") == 5  # A − B, CI low, CI high, p, better
    assert "| 6 |" in psnr_row  # beside its n
    tex = (out / "bootstrap.tex").read_text()
    assert r"$^{\dagger}$ &" in tex and r"fewer than 10 common scenes" in tex
    assert r"\caption{" in tex and tex.count(r"\dagger") >= 6
    assert "⚠" in (out / "analysis.md").read_text()
    index = json.loads((out / "analysis.json").read_text())
    assert index["small_sample"]["min_scenes"] == 10
    assert index["small_sample"]["flagged"]["bootstrap"] == 3
    flag = index["tables"]["bootstrap"]["small_sample"][0]
    assert flag["small_sample"] is True and flag["n"] == 6 and "CI low" in flag["columns"]
    assert index["tables"]["spearman_psnr"]["small_sample"][0]["run"] == "good/threejs"
    assert any("fewer than 10 common scenes" in n for n in index["notes"])
    # the CSV keeps the plain numbers
    assert pd.read_csv(out / "bootstrap.csv")["CI low"].dtype == np.float64
    buf = io.StringIO()
    print_study(few, out, console=Console(file=buf, width=200))
    text = buf.getvalue()
    assert "Spearman ρ over scenes" in text and "common scenes per pair: 1–2: 6" in text
    assert "runs: 1 = " in text and "mean ρ" in text
    assert "fewer than 10 common scenes behind the marked ρ" in text
    assert "⚠ bootstrap: 3 row(s) computed over fewer than 10 common scenes" in text
    # 12 common scenes: no warning anywhere
    many = analyse(_two_runs(tmp_path / "many", 12), tmp_path / "out12", resamples=200)
    assert many.marks == {}
    for f in (tmp_path / "out12").glob("*.md"):
        assert "⚠" not in f.read_text(), f.name
    for f in (tmp_path / "out12").glob("*.tex"):
        assert r"\dagger" not in f.read_text(), f.name
    index = json.loads((tmp_path / "out12" / "analysis.json").read_text())
    assert index["small_sample"]["flagged"] == {}
    assert all("small_sample" not in t for t in index["tables"].values())
    buf = io.StringIO()
    print_study(many, tmp_path / "out12", console=Console(file=buf, width=200))
    assert "⚠" not in buf.getvalue()


def test_analyse_prints_one_spearman_table_and_cuts_no_number(tmp_path):
    """Three runs, two metrics: one table (a row per metric, a column per pair, the mean ρ),
    and on a narrow console every number whole (labels fold, numbers do not)."""
    import io

    from rich.console import Console

    from visphy_core.analysis.printing import fitting_tables, print_study

    rng = np.random.default_rng(3)
    runs = _two_runs(tmp_path / "runs", 12) + [make_run(tmp_path / "mid", "mid", scenes(
        {"psnr": list(rng.uniform(10, 40, 12)), "judge_a": list(rng.uniform(1, 10, 12))}),
        model="mid")]
    out = analyse(runs, tmp_path / "out", resamples=100, metrics=["psnr", "judge_a"])
    buf = io.StringIO()
    print_study(out, console=Console(file=buf, width=200))
    text = buf.getvalue()
    assert text.count("Spearman ρ over scenes") == 1, text
    assert "ρ 1–2" in text and "ρ 1–3" in text and "ρ 2–3" in text
    table = [ln for ln in text.splitlines() if ln.startswith(("│ psnr", "│ judge_a"))]
    assert len(table) == 2, text
    narrow = io.StringIO()
    df = pd.DataFrame({"a label that is rather long for a narrow console": ["x" * 40],
                       "value": [4.70123e-05], "other": [-0.0], "big": [123456.789]})
    for table in fitting_tables(df, None, 40):  # as print_study prints a table
        Console(file=narrow, width=40).print(table, crop=False)
    shown = narrow.getvalue()
    assert "4.701e-05" in shown and "123457" in shown and "…" not in shown
    assert not re.search(r"(?<!e)-0\b", shown)  # no negative zero (an exponent is fine)
    # a frame wider than the console goes on over more tables, each led by its labels
    wide = pd.DataFrame({"metric": ["psnr", "flow_epe_dis"],
                         **{f"ρ {i}–{i + 1}": [0.5 + i / 100, -0.25] for i in range(1, 11)}})
    printed = io.StringIO()
    for table in fitting_tables(wide, None, 60):
        Console(file=printed, width=60).print(table, crop=False)
    lines = printed.getvalue().splitlines()
    assert max(len(line) for line in lines) <= 60
    assert sum(line.startswith("│ psnr ") for line in lines) == len(fitting_tables(wide, None, 60))
    assert all(f"ρ {i}–{i + 1}" in printed.getvalue() for i in range(1, 11))
    assert "0.6" in printed.getvalue() and "…" not in printed.getvalue()
    assert len(fitting_tables(wide, None, 400)) == 1


def test_the_default_columns_start_with_the_runs_headline_score():
    """The analysis' default metrics start with the headline score each run's summary names
    (the number the report and MLflow show first), then the fixed list, then the judges."""
    from visphy_core.analysis.column_views import headline_columns

    run = make_run(None, "r", scenes({"psnr": [20.0, 22.0], "physics_score": [0.4, 0.6],
                                      "judge_a": [5.0, 6.0]}))
    assert headline_columns([run]) == ["psnr", "judge_a"]  # no headline named: not guessed
    run.summary["headline"] = {"metric": "physics_score", "mean": 0.5}
    assert headline_columns([run]) == ["physics_score", "psnr", "judge_a"]
