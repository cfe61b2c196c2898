"""The wheel carries everything a non-editable install needs, and runs from there."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import REPO


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a copy of the tracked files: setuptools writes ``build/`` and
    ``visphy.egg-info`` into the tree it builds, and a stale egg-info in the checkout would
    shadow the editable install's entry points."""
    out = tmp_path_factory.mktemp("wheel")
    src = tmp_path_factory.mktemp("source")
    tracked = subprocess.run(["git", "-C", str(REPO), "ls-files", "-z"], check=True,
                             capture_output=True).stdout.decode().split("\0")
    for name in filter(None, tracked):
        if (REPO / name).is_file() and not (REPO / name).is_symlink():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, src / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                    "-q", "-w", str(out), str(src)], check=True, capture_output=True)
    return next(out.glob("visphy-*.whl"))


def test_wheel_contains_configs_assets_and_templates(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for required in ("visphy_conf/config.yaml", "visphy_conf/engine/threejs.yaml",
                     "visphy_conf/hydra/launcher/local.yaml",
                     "visphy_core/sandbox/virtual_time.js", "visphy_core/calls/prompts/default.txt",
                     "visphy_core/infra/js_vendor/package-lock.json",
                     "visphy_core/spec/replay3d.html",
                     "visphy_plugins/engines/templates/threejs_replay_2d.html"):
        assert required in names, required
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    text = zipfile.ZipFile(wheel).read(entry_points).decode()
    assert "[visphy]" in text and "engine_threejs = visphy_plugins.engines.threejs" in text


@pytest.mark.slow
@pytest.mark.browser
def test_main_command_runs_from_a_non_editable_install(wheel, tmp_path, visphy_home):
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(target), str(wheel)], check=True, capture_output=True)
    env = dict(os.environ, PYTHONPATH=str(target), VISPHY_HOME=str(visphy_home))
    where = subprocess.run([sys.executable, "-c", "import visphy_core, visphy_conf; "
                            "print(visphy_core.__file__, visphy_conf.__file__)"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, check=True)
    assert str(target) in where.stdout and str(REPO) not in where.stdout
    proc = subprocess.run([sys.executable, "-m", "visphy_core", "engine=threejs", "model=oracle",
                           "dataset=mini", "dataset.limit=1", "tracking=none"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "model success 1/1" in proc.stdout
