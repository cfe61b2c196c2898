"""The docs site (mkdocs.yml, docs/): the generated reference pages match the code, the
"Extending" pages include the example plugin's modules as they are, and the site builds with
``mkdocs build --strict`` (a broken link or heading anchor, a missing page or a snippet that
does not exist fails)."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from conftest import REPO

GENERATED = ("reference/cli.md", "reference/config.md", "reference/metrics.md",
             "reference/hooks.md")
EXAMPLE = REPO / "examples" / "visphy-plugin-example" / "visphy_plugin_example"


@pytest.fixture(scope="module")
def stale_pages() -> str:
    """What ``scripts/docs_reference.py --check`` says (one subprocess for every page: the
    script sets the environment it generates in, so this process's plugins and weights never
    leak into a page)."""
    proc = subprocess.run([sys.executable, "scripts/docs_reference.py", "--check"], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode in (0, 1), proc.stderr[-3000:]
    return proc.stdout


@pytest.mark.parametrize("page", GENERATED)
def test_generated_page_matches_the_code(page, stale_pages):
    assert f"docs/{page} " not in stale_pages, (
        f"docs/{page} differs from what the code generates: run "
        "`.venv/bin/python scripts/docs_reference.py` and commit the page")


def test_every_example_module_is_included_in_an_extending_page():
    pages = "".join(p.read_text() for p in (REPO / "docs" / "extending").glob("*.md"))
    included = set(re.findall(r'--8<-- "examples/visphy-plugin-example/visphy_plugin_example/'
                              r'(\w+\.py)"', pages))
    modules = {p.name for p in EXAMPLE.glob("*.py")} - {"__init__.py"}
    assert modules <= included, f"not included in docs/extending/: {sorted(modules - included)}"


def test_the_site_builds_strictly_from_any_directory(tmp_path):
    """Built from outside the checkout (``-f``): the snippets' base path is the config's
    folder, not the working directory."""
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet",
                           "-f", str(REPO / "mkdocs.yml"), "-d", str(tmp_path / "site")],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stderr[-6000:]}"
    assert (tmp_path / "site" / "extending" / "engines" / "index.html").is_file()
