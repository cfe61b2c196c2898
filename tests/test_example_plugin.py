"""The example third-party plugin, pip-installed into the test environment and run via the CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import REPO, run_cli

EXAMPLE = REPO / "examples" / "visphy-plugin-example"


@pytest.fixture(scope="module")
def installed_example():
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run(pip + ["install", "--no-deps", "--no-build-isolation", str(EXAMPLE)],
                   check=True, capture_output=True)
    try:
        yield
    finally:
        subprocess.run(pip + ["uninstall", "-y", "visphy-plugin-example"], check=True,
                       capture_output=True)


def test_listing_shows_the_example_model_and_metric(installed_example, tmp_path):
    out = run_cli("plugins", home=tmp_path).stdout
    row = next(line for line in out.splitlines() if line.startswith("│ example "))
    assert "visphy-plugin-example" in row
    assert "example_still" in out and "example_mae" in out


def test_allow_and_deny_lists_filter_the_plugin(installed_example, tmp_path):
    out = run_cli("plugins", home=tmp_path, env={"VISPHY_DISABLE_PLUGINS": "example"}).stdout
    assert "example_still" not in out and "oracle" in out
    out = run_cli("plugins", home=tmp_path,
                  env={"VISPHY_LOAD_PLUGINS": "visphy-plugin-example,core_configs"}).stdout
    assert "example_still" in out and "oracle" not in out


@pytest.mark.slow
@pytest.mark.browser
def test_example_model_and_metric_appear_in_a_run(installed_example, visphy_home):
    run_cli("model=example_still", "metrics.names=[psnr,example_mae]", "dataset.limit=2",
            "tracking=none", home=visphy_home)
    run_dir = next((visphy_home / "runs").iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["model"] == "example_still"
    mae = summary["metrics"]["example_mae"]
    assert mae["direction"] == "lower" and mae["n_model_success"] == 2
    assert mae["mean_model_success"] > 0  # a still frame differs from a moving scene
    rows = [json.loads(line) for line in (run_dir / "results.jsonl").read_text().splitlines()]
    assert all(r["model_success"] and "static_output" in r["flags"] for r in rows)
