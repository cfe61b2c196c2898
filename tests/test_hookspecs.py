"""Meta-tests (datasette style): every hook has a test and is documented with its signature."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

from visphy_core.api import hookspecs

REPO = Path(__file__).resolve().parents[1]
HOOKS = [name for name, fn in inspect.getmembers(hookspecs, inspect.isfunction)
         if name.startswith("visphy_")]


def test_hooks_follow_the_naming_and_lifecycle_order():
    source = inspect.getsource(hookspecs)
    order = [m.group(1) for m in re.finditer(r"^def (visphy_\w+)\(", source, re.M)]
    assert order == ["visphy_register_configs", "visphy_register_models",
                     "visphy_register_engines", "visphy_register_metrics",
                     "visphy_register_judges", "visphy_register_datasets",
                     "visphy_register_physics", "visphy_run_start", "visphy_scene_done",
                     "visphy_run_end"]
    assert sorted(order) == sorted(HOOKS)


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_has_a_test(hook):
    tests = (REPO / "tests" / "test_plugin_hooks.py").read_text()
    assert re.search(rf"^def test_{hook}\(", tests, re.M), f"no test_{hook} in test_plugin_hooks.py"


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_is_documented_with_its_exact_signature(hook):
    from visphy_core.api.registry import build_plugin_manager

    pm = build_plugin_manager()
    argnames = getattr(pm.hook, hook).spec.argnames
    signature = f"{hook}({', '.join(argnames)})"
    docs = (REPO / "docs" / "reference" / "hooks.md").read_text()
    assert signature in docs, (f"docs/reference/hooks.md does not document `{signature}`: run "
                               "`.venv/bin/python scripts/docs_reference.py`")


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_has_a_docstring(hook):
    doc = inspect.getdoc(getattr(hookspecs, hook))
    assert doc and ":param" in doc
