"""The core's layers (docs/architecture.md): which package may import which, plugins importing
only the plugin API, and no import cycle between modules. Checked statically over every
import statement — at module level, inside functions and under ``TYPE_CHECKING`` alike — so a
cycle hidden by a function-level import still counts."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CORE = REPO / "visphy_core"

#: Each core package (or top-level module) and the core packages it may import. Everything a
#: package imports must be listed under it; a layer never imports one above it.
ALLOWED: dict[str, set[str]] = {
    "infra": set(),
    "api": {"infra"},
    "results": {"infra", "api"},
    "spec": {"infra", "api"},
    "sandbox": {"infra", "api"},
    "calls": {"infra", "api", "spec"},
    "scoring": {"infra", "api", "results", "spec", "calls"},
    "config": {"infra", "api", "scoring"},
    "report": {"infra", "api", "results"},
    "analysis": {"infra", "api", "results"},
    "tracking": {"infra", "api", "results", "report"},
    "leaderboard": {"infra", "api", "results", "report", "analysis"},
    "study": {"infra", "api", "results", "report", "analysis", "tracking"},
    "execute": {"infra", "api", "results", "spec", "sandbox", "calls", "scoring", "config",
                "report", "tracking"},
    "human": {"infra", "api", "results", "execute"},
    "cli": {"infra", "api", "results", "spec", "sandbox", "calls", "scoring", "config",
            "report", "analysis", "tracking", "study", "execute", "human", "leaderboard"},
    "__main__": {"cli"},
    "__init__": set(),
}
#: Modules of ``api/`` that re-export helpers of the layers above it for plugins (what a plugin
#: may use besides the contracts). They may import those layers; no core module imports them.
FACADES = {"media", "sandbox", "calls", "spec", "storage", "scoring"}
FACADE_SOURCES = {"infra", "api", "sandbox", "spec", "calls", "scoring"}
#: What plugins (and the example plugin) may import from the core.
PLUGIN_API = ("visphy_core.api", "visphy_core.results")


def imports_of(path: Path) -> list[tuple[int, str]]:
    """Every module ``path`` imports (absolute imports; ``from m import x`` gives ``m`` and
    ``m.x``, since ``x`` may be a module), and every string passed to ``import_module``,
    ``__import__`` or ``find_spec``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module))
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if called in ("import_module", "__import__", "find_spec"):
                out.append((node.lineno, node.args[0].value))
    return out


def module_name(path: Path, root: Path, package: str) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([package, *parts])


def core_modules(root: Path = CORE) -> dict[str, Path]:
    return {module_name(p, root, "visphy_core"): p for p in sorted(root.rglob("*.py"))}


def layer_of(module: str) -> str:
    """``visphy_core.scoring.score`` → ``scoring``; ``visphy_core`` → ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def layer_violations(modules: dict[str, Path]) -> list[str]:
    bad = []
    for name, path in modules.items():
        src = layer_of(name)
        facade = src == "api" and name.split(".")[-1] in FACADES
        allowed = FACADE_SOURCES if facade else ALLOWED.get(src)
        if allowed is None:
            bad.append(f"{path.relative_to(path.parents[len(name.split('.')) - 1])}: the "
                       f"package {src!r} has no place in the layers (add it to ALLOWED)")
            continue
        for line, target in imports_of(path):
            if not target.startswith("visphy_core.") or target in modules and \
                    layer_of(target) == src:
                continue
            dst = layer_of(target)
            if dst == src:
                continue
            if dst not in allowed:
                bad.append(f"{name}:{line} imports {target} ({src} may not import {dst})")
            if not facade and dst == "api" and target.split(".")[2:3] \
                    and target.split(".")[2] in FACADES:
                bad.append(f"{name}:{line} imports the plugin facade {target} (import the "
                           "module it re-exports)")
    return bad


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module → the modules of ``modules`` it imports (a package's ``__init__`` is not counted
    as imported by its own submodules' relative position)."""
    return {name: {t for _, t in imports_of(path) if t in modules and t != name}
            for name, path in modules.items()}


def test_every_core_package_stays_in_its_layer():
    modules = core_modules()
    assert len(modules) > 60
    assert layer_violations(modules) == []


def test_no_import_cycle_between_core_modules():
    assert cycles(import_graph(core_modules())) == []


def test_plugins_import_only_the_plugin_api():
    offenders = []
    for root in (REPO / "plugins", REPO / "examples"):
        for path in sorted(root.rglob("*.py")):
            for line, target in imports_of(path):
                if target.split(".")[0] == "visphy_core" and target != "visphy_core" \
                        and not target.startswith(PLUGIN_API):
                    offenders.append(f"{path.relative_to(REPO)}:{line}: {target}")
    assert offenders == []


def test_the_checks_catch_a_wrong_import_and_a_cycle(tmp_path):
    """A lower layer importing a higher one, a core module importing a plugin facade, and a
    cycle through a function-level import are each reported (so the tests above can fail)."""
    core = tmp_path / "visphy_core"
    for pkg in ("infra", "api", "execute"):
        (core / pkg).mkdir(parents=True)
        (core / pkg / "__init__.py").write_text("")
    (core / "__init__.py").write_text("")
    (core / "infra" / "a.py").write_text("from visphy_core.execute.b import x\n")
    (core / "execute" / "b.py").write_text("def f():\n    from visphy_core.infra import a\n"
                                           "    from visphy_core.api.media import y\n")
    (core / "api" / "media.py").write_text("from visphy_core.infra import errors\n")
    modules = core_modules(core)
    problems = layer_violations(modules)
    assert any("infra may not import execute" in p for p in problems), problems
    assert any("plugin facade visphy_core.api.media" in p for p in problems), problems
    assert cycles(import_graph(modules)) == [["visphy_core.execute.b", "visphy_core.infra.a"]]


@pytest.mark.parametrize("graph, expected", [
    ({"a": {"b"}, "b": {"c"}, "c": set()}, []),
    ({"a": {"b"}, "b": {"a"}, "c": {"a"}}, [["a", "b"]]),
    ({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"d"}}, [["a", "b", "c"]]),
])
def test_cycle_finder(graph, expected):
    assert cycles(graph) == expected


def test_a_long_module_says_why_it_is_one_module():
    """A module over 500 lines carries a ``# size: <reason>`` line at its top (before its
    first import)."""
    silent = []
    for root in (CORE, REPO / "plugins"):
        for path in sorted(root.rglob("*.py")):
            text = path.read_text()
            lines = text.splitlines()
            first_import = next((node.lineno - 1 for node in ast.parse(text).body
                                 if isinstance(node, (ast.Import, ast.ImportFrom))), len(lines))
            if len(lines) > 500 and not any(line.startswith("# size: ")
                                            for line in lines[:first_import]):
                silent.append(f"{path.relative_to(REPO)} ({len(lines)} lines)")
    assert silent == []


#: Modules outside ``visphy_core/results/`` that may spell a run-file name, with why: the name
#: there is not a run's file.
RUN_FILE_NAME_ELSEWHERE = {
    "visphy_core/config/tree.py": "config.yaml of the Hydra config tree (visphy_conf)",
    "visphy_core/execute/render_cache.py": "video.mp4 of a render cache entry",
    "visphy_core/calls/generation.py": "video.mp4 of a cached reply's entry",
    "plugins/models/baselines.py": "video.mp4 of a baseline's clip in a temporary folder",
}


def run_file_literals(source: str, names: tuple[str, ...]) -> list[tuple[int, str]]:
    """(line, name) for every string literal of ``source`` that names one of ``names`` (the
    whole string, or a path ending in it)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            text = node.value.strip()
            for name in names:
                if text == name or text.endswith("/" + name):
                    found.append((node.lineno, name))
    return sorted(found)


def test_no_run_file_name_outside_results():
    """``results/`` owns the run directory: no other module spells the name of a run's file or
    of a file in a scene's folder (they use `visphy_core.results.run_dir.RunDir` and the names
    of `visphy_core.results.layout`)."""
    from visphy_core.results.layout import FILE_NAMES, SCENE_FILES

    offenders = []
    for root in (CORE, REPO / "plugins", REPO / "examples"):
        for path in sorted(root.rglob("*.py")):
            rel = str(path.relative_to(REPO))
            if rel.startswith("visphy_core/results/") or rel in RUN_FILE_NAME_ELSEWHERE:
                continue
            offenders += [f"{rel}:{line}: {name}"
                          for line, name in run_file_literals(
                              path.read_text(), (*FILE_NAMES, *SCENE_FILES))]
    assert offenders == []


def test_the_run_file_check_catches_a_name():
    """A run file named in a string, alone or at the end of a path, is found; a docstring
    that mentions one in a sentence and a similar name are not (so the test above can fail)."""
    source = ('"""Reads the summary.json of a run."""\n'
              'a = run_dir / "manifest.json"\n'
              'b = "runs/x/results.jsonl"\n'
              'c = "manifest.json.bak"\n')
    assert run_file_literals(source, ("manifest.json", "results.jsonl", "summary.json")) == [
        (2, "manifest.json"), (3, "results.jsonl")]
