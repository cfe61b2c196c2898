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
                     "visphy_plugins/engines/js_vendor/package-lock.json",
                     "visphy_plugins/engines/templates/threejs_replay_3d.html",
                     "visphy_plugins/engines/templates/threejs_replay_2d.html",
                     # the shipped catalogue (a fresh home simulates nothing) and its digest
                     "visphy_plugins/datasets/visphybench/data/catalogue-v3-seed0.json.gz",
                     "visphy_plugins/datasets/visphybench/data/catalogues.json"):
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


def _conf_options() -> dict[str, set[str]]:
    """Every config group of ``conf/`` and its options (its YAML files), as ``run --help``
    should list them."""
    conf = REPO / "conf"
    groups: dict[str, set[str]] = {}
    for path in conf.rglob("*.yaml"):
        group = path.parent.relative_to(conf).as_posix()
        if group != "." and group != "hydra/callbacks":
            groups.setdefault(group, set()).add(path.stem)
    return groups


def _project() -> dict:
    import tomllib

    return tomllib.loads((REPO / "pyproject.toml").read_text())["project"]


def _entry_points() -> set[str]:
    return set(_project()["entry-points"]["visphy"])


@pytest.fixture(scope="module")
def fresh_venv(wheel, tmp_path_factory) -> Path:
    """A fresh venv (``python -m venv``) with the wheel installed by pip, ``--no-deps``: the
    wheel's own files, dist-info and ``bin/visphy``. The dependencies come from the project's
    ``.venv``: a ``.pth`` file in the fresh venv's site-packages names the site-packages of the
    interpreter running the tests, appended after the fresh venv's own. Python does not process
    ``.pth`` files in a directory a ``.pth`` line adds, so the checkout's editable install (a
    ``.pth`` finder there) stays out, and its ``visphy`` dist-info comes after the wheel's."""
    import sysconfig

    venv = tmp_path_factory.mktemp("fresh") / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True,
                   capture_output=True)
    python = venv / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; "
                                "print(sysconfig.get_paths()['purelib'])"], check=True,
                               capture_output=True, text=True).stdout.strip())
    (site / "project_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install",
                    "--no-deps", "-q", str(wheel)], check=True, capture_output=True)
    return venv


def _fresh(venv: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items()
           if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME")}
    env["PATH"] = f"{venv / 'bin'}:/usr/bin:/bin"
    proc = subprocess.run(list(args), cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return proc


def test_a_fresh_venv_gets_visphy_with_every_plugin_and_config(fresh_venv, tmp_path):
    """The wheel in a fresh venv: its own ``bin/visphy``, run from outside the checkout, finds
    every built-in plugin (the entry points of pyproject.toml) and every config group and option
    of ``conf/``; every package imports from the fresh venv, none from the checkout."""
    visphy = str(fresh_venv / "bin" / "visphy")
    assert Path(visphy).is_file()
    where = _fresh(fresh_venv, str(fresh_venv / "bin" / "python"), "-c", (
        "import importlib.metadata as md, visphy_core, visphy_plugins, visphy_conf, "
        "visphy_plugins.engines.threejs as t; "
        "print(visphy_core.__file__, visphy_plugins.__file__, visphy_conf.__file__, t.__file__, "
        "md.distribution('visphy').locate_file(''))"), cwd=tmp_path)
    paths = where.stdout.split()
    assert len(paths) == 5
    for path in paths:
        assert Path(path).resolve().is_relative_to(fresh_venv.resolve()), path
        assert not Path(path).resolve().is_relative_to(REPO.resolve()), path

    plugins = _fresh(fresh_venv, visphy, "plugins", cwd=tmp_path).stdout
    listed = {line.split("│")[1].strip() for line in plugins.splitlines()
              if line.startswith("│") and line.split("│")[1].strip()}
    assert listed == _entry_points()
    # every plugin from one distribution, the wheel's
    assert plugins.count(f"visphy {_project()['version']}") == len(_entry_points())

    usage = _fresh(fresh_venv, visphy, "run", "--help", cwd=tmp_path).stdout
    shown = {line.split(":", 1)[0].strip(): {o.strip().rstrip("*")
                                               for o in line.split(":", 1)[1].split(",")}
             for line in usage.split("config groups", 1)[1].split("\n\n", 1)[0].splitlines()[1:]}
    for group, options in _conf_options().items():
        assert group in shown, (group, usage)
        assert options <= shown[group], (group, options - shown[group])

    # the shipped catalogue is read from the installed package, its digest checked
    shipped = _fresh(fresh_venv, str(fresh_venv / "bin" / "python"), "-c", (
        "from visphy_plugins.datasets.visphybench.build import shipped_catalogue; "
        "from visphy_plugins.datasets.visphybench.shipped import DATA; "
        "print(len(shipped_catalogue(0).entries), DATA)"), cwd=tmp_path).stdout.split()
    assert shipped[0] == "209" and Path(shipped[1]).resolve().is_relative_to(fresh_venv.resolve())
