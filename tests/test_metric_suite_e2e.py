"""The whole offline metric suite (``metrics=appearance``: the default suite and the paper's
appearance metrics that need no weights) through the real CLI: every metric gives a number or
says why not, the oracle scores near perfect, the frozen baseline scores far worse on physics."""

from __future__ import annotations

import json

import pytest
from omegaconf import OmegaConf

from conftest import REPO, run_cli

pytestmark = [pytest.mark.slow, pytest.mark.browser,
              # the first test's setup runs the oracle and the baseline through the whole
              # offline suite (193 s on a loaded 2-core dev box, the mini build included)
              pytest.mark.timeout(900)]

DEFAULT = list(OmegaConf.load(REPO / "conf" / "metrics" / "default.yaml").names)
OFFLINE = list(OmegaConf.load(REPO / "conf" / "metrics" / "appearance.yaml").names)


def _run(home, model: str, *more: str) -> tuple[dict, dict, object]:
    # normalisation off: its anchors would score the twin and the still clip with the whole
    # suite as well (tests/test_variance_norm.py and tests/test_gt_store.py cover them)
    run_cli(f"model={model}", "metrics=appearance", "metrics.variance_norm=false",
            "tracking=none", "run.progress=false", *more, home=home)
    run_dir = max((home / "runs").iterdir(), key=lambda p: p.stat().st_mtime)
    rows = {r["scene_id"]: r for r in map(json.loads, (run_dir / "results.jsonl").open())}
    return json.loads((run_dir / "summary.json").read_text()), rows, run_dir


@pytest.fixture(scope="module")
def oracle_and_static(tmp_path_factory, mini_root):
    import shutil

    home = tmp_path_factory.mktemp("suite") / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return _run(home, "oracle"), _run(home, "static", "dataset.limit=2")


def test_every_offline_metric_is_scored_or_says_why(oracle_and_static):
    (summary, rows, run_dir), _ = oracle_and_static
    metrics = summary["metrics"]
    assert set(DEFAULT) < set(OFFLINE)  # the default suite is part of the offline one
    for name in OFFLINE:
        m = metrics[name]
        assert m["unavailable"] is None, (name, m["unavailable"])
        if not name.startswith("param_"):  # a parameter may be revealed by no mini scene
            assert m["n_model_success"] == summary["n_scenes"], name
    # the views: unaligned, aligned and paper for every frame/sequence metric
    for name in ("psnr", "st_lpips", "flow_epe_dis", "track_pos_err"):
        for col in (name, f"{name}.aligned", f"paper.{name}", f"spec.{name}"):
            assert metrics[col]["mean_model_success"] is not None, col
    # BERTScore says which model it used; ST-LPIPS which net
    assert "MiniLM" in json.dumps(summary["metric_info"]["bertscore_minilm"])
    assert summary["metric_info"]["st_lpips"]["weights"]
    details = json.loads(next(run_dir.glob("scenes/*/metric_details.json")).read_text())
    assert {"param_recovery", "tracks"} <= set(details)
    assert details["tracks"]["tracked"]


def test_the_oracle_is_near_perfect(oracle_and_static):
    (summary, rows, _), _ = oracle_and_static
    m = {k: v["mean_model_success"] for k, v in summary["metrics"].items()}
    assert m["psnr"] > 40 and m["ssim"] > 0.99 and m["ms_ssim"] > 0.99
    assert m["fsim"] > 0.99 and m["vsi"] > 0.99 and m["st_lpips"] < 0.01
    assert m["track_pos_err"] < 0.5 and m["track_vel_err"] < 2.0
    assert m["flow_epe_dis"] < 0.05
    # every event and parameter metric is scored here (each mini scene has its events, and
    # each parameter is revealed by at least one mini scene): a missing one is a failure
    for name in ("event_contact_err", "event_exit_err"):
        # sub-frame event times: the oracle's render differs from the ground truth by a few
        # edge pixels, so its times may differ by a millisecond, never by a frame (0.2 s)
        assert m[name] is not None and 0.0 <= m[name] < 0.01, (name, m[name])
    # coming to rest is fragile (README, known weak): a body hovering at the rest threshold in
    # one clip only costs the clip's duration; on the mini scenes the oracle still stays < 1 s
    assert m["event_rest_err"] is not None and 0.0 <= m["event_rest_err"] < 1.0
    for name in DEFAULT:
        if name.startswith("param_"):
            assert summary["metrics"][name]["n_model_success"] >= 1, name
            assert m[name] == pytest.approx(0.0, abs=1e-9), name
    assert m["rouge_l"] == pytest.approx(1.0)
    assert m["bertscore_minilm"] == pytest.approx(1.0, abs=1e-4)


def test_the_frozen_baseline_is_far_worse_on_physics(oracle_and_static):
    (oracle, _, _), (static, _, _) = oracle_and_static
    o = {k: v["mean_with_fallbacks"] for k, v in oracle["metrics"].items()}
    s = {k: v["mean_with_fallbacks"] for k, v in static["metrics"].items()}
    for name in ("track_pos_err", "track_vel_err", "flow_epe_dis", "flow_epe_moving_dis",
                 "st_lpips"):
        assert s[name] > 10 * max(o[name], 1e-3), name
    assert s["psnr"] < o["psnr"]
    # a pixel-space model writes no S and no program: no parameter is determinable
    assert all(s[n] is None for n in DEFAULT if n.startswith("param_"))
