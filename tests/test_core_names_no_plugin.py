"""The core knows no built-in plugin by name: what an engine, a dataset, a model, a judge or a
simulator is called, and the JavaScript libraries an engine vendors, come from the registry.

The names are taken from what the installed built-in plugins register (and the packages of the
engine and dataset plugins, and the engines' declared JavaScript assets), so a new built-in is
checked without editing this file. A name that is also an everyday word (``original``,
``static``, ``replay``…) counts only where it selects a plugin (``model=replay``); any other
counts anywhere in a core file's text, comments included. An exception would go in
`ALLOWED`, with its reason; an entry that no longer matches fails too. It is empty.
"""

from __future__ import annotations

import ast
import re
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from visphy_core.api.assets import engine_assets
from visphy_core.api.dataset import Dataset, GroundTruth
from visphy_core.api.registry import Registry, get_registry

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "visphy_core"
SUFFIXES = {".py", ".js", ".mjs", ".html", ".css", ".txt", ".md", ".json"}
#: Data, not code: a study's results (metric and engine names are its row labels).
SKIP = {"visphy_core/api/validity_summary.json"}
KINDS = ("engines", "datasets", "models", "judges", "physics")
#: Names that are everyday words (or a file format): they count only where they select a plugin.
COMMON = {"original", "generated", "tiny", "static", "replay", "svg", "hf", "three", "cannon"}
#: The library's own name, which no lock file spells.
EXTRA_ASSET_NAMES = {"three.js"}
GROUPS = r"(?:engine|model|dataset|judge|source|physics)(?:\.name|\.source)?"

#: file -> (names it may contain, why). Empty: a core file that must name a built-in plugin
#: says why here, and the check holds it to exactly those names.
ALLOWED: dict[str, tuple[set[str], str]] = {}


def builtin_names() -> set[str]:
    """What the built-in plugins register, the packages of the engine and dataset plugins, and
    the engines' JavaScript libraries and npm packages."""
    registry = get_registry()
    builtin = {ep.name for ep in entry_points(group="visphy")
               if ep.value.startswith("visphy_plugins.")}
    names = {name for kind in KINDS for name, (_obj, plugin) in getattr(registry, kind).items()
             if plugin in builtin}
    for ep in entry_points(group="visphy"):
        parts = ep.value.split(":")[0].split(".")
        if parts[:2] in (["visphy_plugins", "engines"], ["visphy_plugins", "datasets"]):
            names.add(parts[2])
    for assets in engine_assets(registry):
        names |= set(assets.libraries) | set(assets.locked_versions())
    return {n.lower() for n in names} | EXTRA_ASSET_NAMES


def named_plugins(text: str, names: set[str], python: bool = False) -> set[str]:
    """The built-in names ``text`` mentions (lower case)."""
    distinct = sorted(names - COMMON, key=len, reverse=True)
    word = re.compile(r"(?<![\w.-])(" + "|".join(map(re.escape, distinct)) + r")(?![\w-])",
                      re.I)
    selects = re.compile(rf"\b{GROUPS}=\[?(?:[\w-]+,)*(" + "|".join(
        map(re.escape, sorted(names, key=len, reverse=True))) + r")\b")
    found = {m.group(1).lower() for m in word.finditer(text)}
    found |= {m.group(1).lower() for m in selects.finditer(text)}
    if python:
        found |= {node.value for node in ast.walk(ast.parse(text))
                  if isinstance(node, ast.Constant) and node.value in names - COMMON}
    return found


def core_files() -> list[Path]:
    return sorted(p for p in CORE.rglob("*") if p.is_file() and p.suffix in SUFFIXES
                  and "__pycache__" not in p.parts
                  and p.relative_to(ROOT).as_posix() not in SKIP)


@pytest.fixture(scope="module")
def names() -> set[str]:
    return builtin_names()


def test_the_names_come_from_the_installed_plugins(names):
    assert {"threejs", "p5", "svg", "manim", "blender"} <= names
    assert {"visphybench", "original", "tiny", "hf", "oracle"} <= names
    assert {"three.min.js", "matter-js", "three.js"} <= names


def test_no_core_module_names_a_builtin_plugin(names):
    problems, seen = [], {}
    for path in core_files():
        rel = path.relative_to(ROOT).as_posix()
        found = named_plugins(path.read_text(errors="replace"), names, path.suffix == ".py")
        seen[rel] = found
        allowed = ALLOWED.get(rel, (set(), ""))[0]
        problems += [f"{rel} names {n!r}" for n in sorted(found - allowed)]
    problems += [f"{rel}: allowed {sorted(allowed - seen.get(rel, set()))} no longer named "
                 "(shrink ALLOWED)" for rel, (allowed, _why) in ALLOWED.items()
                 if allowed - seen.get(rel, set())]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("source, name", [
    ('ENGINE = "threejs"\n', "threejs"),
    ("# serves /vendor/three.min.js\n", "three.min.js"),
    ('HELP = "visphy model=replay dataset=tiny"\n', "replay"),
    ('if cfg.source == "visphybench": pass\n', "visphybench"),
    ('"""Draws with Three.js."""\n', "three.js"),
])
def test_the_check_fails_on_a_fixture(names, source, name):
    assert name in named_plugins(source, names, python=True)


def test_everyday_words_count_only_where_they_select_a_plugin(names):
    text = '"""The original clip, generated once; a static frame."""\nX = "replay"\n'
    assert named_plugins(text, names, python=True) == set()


class _Elsewhere(Dataset):
    name = "elsewhere"

    def locate_ground_truth(self, run, scene_ids):
        root = run.paths(run.cfg("dataset.root", None))[0]
        return {sid: GroundTruth(sid, root=root, video=root / f"{sid}.clip")
                for sid in scene_ids if (root / f"{sid}.clip").is_file()}


def test_the_report_asks_the_runs_dataset_where_its_ground_truth_is(tmp_path, monkeypatch):
    from visphy_core.api import registry as registry_module
    from visphy_core.report.locate_truth import locate_ground_truth
    from visphy_core.results.load import RunData

    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "s1.clip").write_bytes(b"")
    registry = Registry(datasets={"elsewhere": (_Elsewhere, "inline"),
                                  "quiet": (Dataset, "inline")})
    monkeypatch.setattr(registry_module, "get_registry", lambda: registry)
    run_dir = tmp_path / "runs" / "r"
    run_dir.mkdir(parents=True)

    def run(source):
        cfg = {"paths": {"runs_dir": "runs"}, "dataset": {"source": source, "root": "data"}}
        return RunData(run_dir=run_dir, config=cfg, manifest={}, summary={}, results=[])

    got = locate_ground_truth(run("elsewhere"), ["s1", "s2"])
    assert got["s1"].video == tmp_path / "data" / "s1.clip" and got["s1"].missing is None
    assert "not found" in got["s2"].missing
    assert "does not say" in locate_ground_truth(run("quiet"), ["s1"])["s1"].missing
    assert "not an installed dataset" in locate_ground_truth(run("gone"), ["s1"])["s1"].missing
