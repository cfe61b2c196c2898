"""The validity study's figures where users meet them: the metric registry, the generated docs
page, and `analyse`'s warning when two runs differ by less than the discriminative power."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from visphy_core.analysis.study import below_power
from visphy_core.api.registry import get_registry
from visphy_core.api.validity import figures, load_summary, power_at
from visphy_core.results.load import RunData


def _summary(power_49: float = 0.02) -> dict:
    return {"scores": {"headline": {"strict": {"scenes": 49, "ordered": 45, "share": 45 / 49},
                                    "means": {"share": 1.0}, "monotone": {"share": 0.95},
                                    "invariance": {"max_median": 0.04},
                                    "physics_drop": {"min_median": 0.25}}},
            "discriminative_power": {"wrong": {"n_scenes": {"49": {"median": power_49}}}}}


def test_figures_come_from_the_summary_and_absent_scores_are_none():
    fig = figures("headline", _summary())
    assert fig["strict"] == 45 / 49 and fig["monotone"] == 0.95
    assert fig["invariance"] == 0.04 and fig["physics_drop"] == 0.25 and fig["scenes"] == 49
    assert figures("psnr", _summary()) is None
    assert figures("headline", {}) is None


def test_power_shrinks_with_the_square_root_of_the_scenes():
    s = _summary(0.02)
    assert power_at(49, s) == 0.02
    assert abs(power_at(196, s) - 0.01) < 1e-12
    assert power_at(1, s) is None and power_at(49, {}) is None


def test_the_registry_and_the_shipped_summary_agree():
    shipped = load_summary()
    assert shipped is not None, "visphy_core/api/validity_summary.json is shipped"
    registry = get_registry()
    for name in shipped["scores"]:
        if name in registry.metrics:
            assert registry.get("metrics", name).describe()["validity"] == figures(name)


def _run(label: str) -> RunData:
    run = RunData(Path(label), {}, {}, {"headline": {"metric": "physics_score"}}, [])
    return run


def test_analyse_calls_a_difference_below_the_power_a_tie(monkeypatch):
    import visphy_core.api.validity as validity

    monkeypatch.setattr(validity, "load_summary", lambda path=None: _summary(0.05))
    table = pd.DataFrame([
        {"metric": "physics_score ↑", "A": "a", "B": "b", "n common": 49, "mean A": 0.60,
         "mean B": 0.58, "A − B": 0.02, "CI low": -0.01, "CI high": 0.05, "p": 0.2,
         "better": ""},
        {"metric": "physics_score ↑", "A": "a", "B": "c", "n common": 49, "mean A": 0.60,
         "mean B": 0.40, "A − B": 0.20, "CI low": 0.1, "CI high": 0.3, "p": 0.001,
         "better": "a"},
        {"metric": "psnr ↑", "A": "a", "B": "b", "n common": 49, "mean A": 20, "mean B": 20.01,
         "A − B": -0.01, "CI low": -1, "CI high": 1, "p": 0.9, "better": ""}])
    notes = below_power([_run("a"), _run("b")], table)
    assert len(notes) == 1 and "`a` − `b`" in notes[0] and "tie" in notes[0]
