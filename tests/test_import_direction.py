"""The dependency direction: the core imports no plugin (plugins import the core, never the
reverse), checked statically over every core module and at run time with the plugins
unimportable; and the datasets are plugins the CLI lists."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from conftest import run_cli

REPO = Path(__file__).resolve().parents[1]
CORE = REPO / "visphy_core"
PLUGIN_PACKAGES = ("visphy_plugins",)


def _plugin_references(path: Path) -> list[str]:
    """Every import of a plugin package in ``path``, and every string naming one that is
    passed to an import function (``importlib.import_module("visphy_plugins...")``)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if called in ("import_module", "__import__", "find_spec"):
                names = [node.args[0].value]
        for name in names:
            if name.split(".")[0] in PLUGIN_PACKAGES:
                found.append(f"{path.relative_to(REPO)}:{node.lineno}: {name}")
    return found


def test_no_core_module_imports_a_plugin():
    modules = sorted(CORE.rglob("*.py"))
    assert len(modules) > 40
    offenders = [ref for path in modules for ref in _plugin_references(path)]
    assert offenders == []


def test_the_check_sees_every_form_of_import(tmp_path):
    """The static check would catch each way of importing a plugin (so the test above can
    fail)."""
    bad = tmp_path / "bad.py"
    bad.write_text("import visphy_plugins.engines\n"
                   "from visphy_plugins.metrics import pixel\n"
                   "def f():\n"
                   "    import importlib\n"
                   "    return importlib.import_module('visphy_plugins.models.oracle')\n")
    old_repo = globals()["REPO"]
    try:
        globals()["REPO"] = tmp_path
        refs = _plugin_references(bad)
    finally:
        globals()["REPO"] = old_repo
    assert [r.split(": ")[1] for r in refs] == ["visphy_plugins.engines",
                                                "visphy_plugins.metrics",
                                                "visphy_plugins.models.oracle"]


def test_every_core_module_imports_with_the_plugins_unimportable():
    code = """
import importlib, pkgutil, sys
sys.modules["visphy_plugins"] = None          # any import of a plugin now fails
import visphy_core
failed = []
for mod in pkgutil.walk_packages(visphy_core.__path__, "visphy_core."):
    if mod.name.endswith("__main__"):
        continue
    try:
        importlib.import_module(mod.name)
    except Exception as exc:
        failed.append(f"{mod.name}: {type(exc).__name__}: {exc}")
print(len(failed), "failed")
print("\\n".join(failed))
sys.exit(1 if failed else 0)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=REPO, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr


def test_plugins_command_lists_the_dataset_and_physics_plugins(tmp_path):
    out = run_cli("plugins", home=tmp_path).stdout
    for name in ("dataset_visphybench", "dataset_original", "dataset_tiny",
                 "physics_box2d", "physics_cannon"):
        assert name in out, name
    assert "datasets: generated" in out and "datasets: tiny" in out
    assert "physics: box2d" in out and "physics: cannon-es" in out


def test_a_run_on_the_tiny_dataset_plugin(tmp_path):
    """``dataset=tiny``: the fixture plugin writes its scenes under the data dir on first use
    and a run evaluates all three."""
    run_cli("dataset=tiny", "model=static", "tracking=none", "run.progress=false",
            home=tmp_path)
    assert sorted(p.name for p in (tmp_path / "data" / "tiny" / "sub" / "videos").iterdir()) \
        == ["task10000_000.mp4", "task10001_000.mp4", "task10002_000.mp4"]
    run_dir = next((tmp_path / "runs").iterdir())
    rows = (run_dir / "results.jsonl").read_text().splitlines()
    assert len(rows) == 3
