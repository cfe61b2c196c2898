"""docs/architecture.md walks one scene through the code as ``path.py::name`` references: each
must name a function or class that exists in that module (the page cannot drift from the code)."""

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REFERENCE = re.compile(r"`([a-z_/0-9]+\.py)::([A-Za-z_.]+)`")


def missing_references(text: str, root: Path = REPO) -> list[str]:
    """The ``path::name`` references of ``text`` whose module or definition is not there."""
    missing = []
    for path, name in REFERENCE.findall(text):
        candidates = [root / "visphy_core" / path, root / path,
                      root / "plugins" / path.removeprefix("plugins/")]
        last = name.split(".")[-1]
        if not any(p.is_file() and re.search(rf"^\s*(async def|def|class) {last}\b",
                                              p.read_text(), re.M) for p in candidates):
            missing.append(f"{path}::{name}")
    return missing


def test_every_reference_names_a_definition():
    text = (REPO / "docs" / "architecture.md").read_text()
    assert len(REFERENCE.findall(text)) >= 10
    assert missing_references(text) == []


def test_a_moved_function_is_caught():
    assert missing_references("`execute/pipeline.py::no_such_function`") == \
        ["execute/pipeline.py::no_such_function"]
    assert missing_references("`execute/nowhere.py::process_scene`") == \
        ["execute/nowhere.py::process_scene"]
    assert missing_references("`execute/pipeline.py::process_scene`") == []
