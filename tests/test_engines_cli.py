"""`python -m visphy_core engine=<each engine> model=oracle dataset=mini` runs end to end."""

from __future__ import annotations

import json

import pytest

from conftest import run_cli
from visphy_core.api.registry import get_registry

ENGINES = sorted(get_registry().engines)


def test_all_five_engines_are_registered():
    assert {"threejs", "p5", "svg", "manim", "blender"} <= set(ENGINES)


@pytest.mark.slow
@pytest.mark.browser
@pytest.mark.parametrize("engine", ENGINES)
def test_oracle_runs_on_every_engine(engine, visphy_home):
    proc = run_cli(f"engine={engine}", "model=oracle", "dataset=mini", "dataset.limit=1",
                   "tracking=none", home=visphy_home)
    assert "model success 1/1" in proc.stdout, proc.stdout[-2000:]
    run_dir = next((visphy_home / "runs").iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["engine"] == engine
    assert summary["metrics"]["psnr"]["mean_model_success"] >= 30
