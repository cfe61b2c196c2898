"""No function or method in ``visphy_core/`` or ``plugins/`` runs over 100 lines without a stated
reason. A function's length is counted from its ``def`` line to the last line of its body,
inclusive (decorators excluded; docstring, comments and blank lines inside the body included), so
the number is what a reader scrolls through. A longer function passes only when a
``# long: <reason>`` comment stands in the comment lines right above its ``def`` (above its
decorators, if it has any) or on its first body line (or the comment lines right before it); the
reason may continue on the following comment lines."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ROOTS = (REPO / "visphy_core", REPO / "plugins")
LIMIT = 100
MARK = "# long: "


def _has_reason(lines: list[str], node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    top = min([node.lineno, *(d.lineno for d in node.decorator_list)])
    first_body = node.body[0].lineno
    candidates = [first_body]
    # the comment block right above the def (or its decorators), and right above the first body
    # line: a reason may run over several comment lines
    for start in (top - 1, first_body - 1):
        number = start
        while 1 <= number <= len(lines) and lines[number - 1].strip().startswith("#"):
            candidates.append(number)
            number -= 1
    for number in candidates:
        if 1 <= number <= len(lines):
            text = lines[number - 1].strip()
            if text.startswith(MARK) and text[len(MARK):].strip():
                return True
    return False


def long_functions(source: str) -> list[tuple[str, int, int, bool]]:
    """``(name, line, length, has_reason)`` for each function over ``LIMIT`` lines in ``source``."""
    lines = source.splitlines()
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = node.end_lineno - node.lineno + 1
            if length > LIMIT:
                found.append((node.name, node.lineno, length, _has_reason(lines, node)))
    return found


def _unexplained(source: str) -> list[tuple[str, int, int]]:
    return [(name, line, length) for name, line, length, ok in long_functions(source) if not ok]


def test_no_long_function_without_a_reason():
    bad = []
    for root in ROOTS:
        for path in sorted(root.rglob("*.py")):
            for name, line, length in _unexplained(path.read_text(encoding="utf-8")):
                bad.append(f"{path.relative_to(REPO)}:{line} {name} ({length} lines)")
    assert not bad, ("functions over 100 lines: split them, or state why not with a "
                     "'# long: <reason>' line above the def:\n" + "\n".join(bad))


def _fixture(length: int, before: str = "", first: str = "") -> str:
    body = "".join(f"    x{i} = {i}\n" for i in range(length - 1 - bool(first)))
    return f"import os\n{before}def f():\n{first}{body}"


def test_the_check_catches_a_long_function():
    assert long_functions(_fixture(100)) == []
    assert _unexplained(_fixture(101)) == [("f", 2, 101)]
    assert _unexplained(_fixture(101, before="# long: a table read as one\n")) == []
    assert _unexplained(_fixture(101, first="    # long: one state machine\n")) == []
    two_lines = "# long: a reason that runs\n# over two comment lines\n"
    assert _unexplained(_fixture(101, before=two_lines)) == []
    # A '# long:' separated from the def by code is not the def's reason.
    assert _unexplained(_fixture(101, before="# long: elsewhere\nX = 1\n")) != []
    # An empty reason is no reason.
    assert _unexplained(_fixture(101, before="# long:\n")) != []


def test_methods_and_decorated_functions_count():
    source = ("class A:\n    @staticmethod\n    def g():\n"
              + "".join(f"        y{i} = {i}\n" for i in range(120)))
    assert _unexplained(source) == [("g", 3, 121)]
    marked = source.replace("class A:\n", "class A:\n    # long: generated table\n")
    assert _unexplained(marked) == []
