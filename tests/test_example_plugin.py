"""The example third-party plugin, pip-installed and run via the CLI.

It is installed into a private target folder that only this file's CLI subprocesses see (on
their PYTHONPATH), never into the shared .venv: other test files run at the same time (xdist
workers) and must not discover, or lose halfway, a plugin they did not ask for. Entry points
are found there as in site-packages (importlib.metadata reads every sys.path entry's
*.dist-info)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

from conftest import REPO, run_cli

EXAMPLE = REPO / "examples" / "visphy-plugin-example"


@pytest.fixture(scope="module")
def installed_example(tmp_path_factory) -> dict:
    """The env that puts the installed example plugin on a subprocess's path."""
    base = tmp_path_factory.mktemp("example-plugin")
    source = base / "src"  # a copy: building in place would leave build/ files in the repo
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    target = base / "site"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run(pip + ["install", "--no-deps", "--no-build-isolation", "--target",
                          str(target), str(source)], check=True, capture_output=True)
    assert list(target.glob("visphy_plugin_example-*.dist-info/entry_points.txt"))
    path = os.pathsep.join(p for p in (str(target), os.environ.get("PYTHONPATH")) if p)
    return {"PYTHONPATH": path}


def test_listing_shows_the_example_model_and_metric(installed_example, tmp_path):
    out = run_cli("plugins", home=tmp_path, env=installed_example).stdout
    row = next(line for line in out.splitlines() if line.startswith("│ example "))
    assert "visphy-plugin-example" in row
    assert "example_still" in out and "example_mae" in out


def test_allow_and_deny_lists_filter_the_plugin(installed_example, tmp_path):
    out = run_cli("plugins", home=tmp_path,
                  env={**installed_example, "VISPHY_DISABLE_PLUGINS": "example"}).stdout
    assert "example_still" not in out and "oracle" in out
    out = run_cli("plugins", home=tmp_path,
                  env={**installed_example,
                       "VISPHY_LOAD_PLUGINS": "visphy-plugin-example,core_configs"}).stdout
    assert "example_still" in out and "oracle" not in out


@pytest.mark.slow
@pytest.mark.browser
def test_example_model_and_metric_appear_in_a_run(installed_example, visphy_home):
    run_cli("model=example_still", "metrics.names=[psnr,example_mae]", "dataset.limit=2",
            "tracking=none", home=visphy_home, env=installed_example)
    run_dir = next((visphy_home / "runs").iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["model"] == "example_still"
    mae = summary["metrics"]["example_mae"]
    assert mae["direction"] == "lower" and mae["n_model_success"] == 2
    assert mae["mean_model_success"] > 0  # a still frame differs from a moving scene
    rows = [json.loads(line) for line in (run_dir / "results.jsonl").read_text().splitlines()]
    assert all(r["model_success"] and "static_output" in r["flags"] for r in rows)
