"""The model's physical spec S beside the ground-truth spec, with the differing lines marked.

Both are printed the same way so that equal content gives equal lines: keys sorted, lists of
plain values on one line, bodies ordered by id, numbers to 4 significant figures (the exact
files are folded below the diff). The ground truth is cut to the keys S has (the benchmark's
spec holds much the model is not asked for: difficulty labels, solver settings); bodies S lacks
stay, so a missed object shows as an added block. The diff is a plain line diff
(`difflib.SequenceMatcher`) showing
`CONTEXT` equal lines around each difference.
"""

from __future__ import annotations

import difflib
import json
from typing import Any

from visphy_core.report.markup import esc

#: Equal lines kept around each difference; longer runs of equal lines are folded to one row.
CONTEXT = 3


def _is_plain(value: Any) -> bool:
    return not isinstance(value, (dict, list)) or (
        isinstance(value, list) and all(not isinstance(v, (dict, list)) for v in value))


def _round(value: Any) -> Any:
    if isinstance(value, float):
        return float(f"{value:.4g}")
    if isinstance(value, list):
        return [_round(v) for v in value]
    if isinstance(value, dict):
        return {k: _round(v) for k, v in value.items()}
    return value


def _by_id(items: list) -> list:
    if items and all(isinstance(i, dict) and "id" in i for i in items):
        return sorted(items, key=lambda i: str(i["id"]))
    return items


def _lines(value: Any, indent: int = 0, key: str | None = None) -> list[str]:
    pad = "  " * indent
    head = f"{pad}{json.dumps(key)}: " if key is not None else pad
    if _is_plain(value) or (isinstance(value, list) and all(_is_plain(v) for v in value)
                            and len(json.dumps(value)) <= 72):
        return [head + json.dumps(value, ensure_ascii=False)]
    if isinstance(value, dict):
        out = [head + "{"]
        for k in sorted(value, key=str):
            out += _lines(value[k], indent + 1, str(k))
        return out + [pad + "}"]
    out = [head + "["]
    for item in _by_id(value):
        out += _lines(item, indent + 1)
    return out + [pad + "]"]


def spec_lines(spec: Any) -> list[str]:
    """``spec`` printed for the diff (see the module docstring)."""
    return _lines(_round(spec))


def restrict(truth: Any, model: Any) -> Any:
    """``truth`` cut to the keys ``model`` has, recursively; bodies are matched by id (a body
    S lacks is cut to the keys of S's first body)."""
    if isinstance(truth, dict) and isinstance(model, dict):
        return {k: restrict(v, model[k]) for k, v in truth.items() if k in model}
    if isinstance(truth, list) and isinstance(model, list) and model:
        if all(isinstance(i, dict) for i in truth) and all(isinstance(i, dict) for i in model):
            by_id = {i.get("id"): i for i in model}
            return [restrict(t, by_id.get(t.get("id"), model[0])) for t in truth]
    return truth


def diff_table(model: Any, truth: Any) -> tuple[str, int]:
    """An HTML table: S on the left, the (restricted) ground truth on the right; and the number
    of differing lines."""
    left, right = spec_lines(model), spec_lines(restrict(truth, model))
    rows: list[str] = []
    changed = 0
    matcher = difflib.SequenceMatcher(None, left, right, autojunk=False)
    opcodes = matcher.get_opcodes()
    for position, (op, i1, i2, j1, j2) in enumerate(opcodes):
        if op == "equal":
            pairs = list(zip(left[i1:i2], right[j1:j2]))
            head = CONTEXT if position > 0 else 0
            tail = CONTEXT if position < len(opcodes) - 1 else 0
            if len(pairs) > head + tail + 1:
                hidden = len(pairs) - head - tail
                pairs = [*pairs[:head], None, *pairs[len(pairs) - tail:]]
            for pair in pairs:
                if pair is None:
                    rows.append(f'<tr class="skip"><td colspan="2">… {hidden} equal line(s)'
                                "</td></tr>")
                else:
                    rows.append(f'<tr><td class="l">{esc(pair[0])}</td>'
                                f'<td class="r">{esc(pair[1])}</td></tr>')
            continue
        a_part, b_part = left[i1:i2], right[j1:j2]
        changed += max(len(a_part), len(b_part))
        for k in range(max(len(a_part), len(b_part))):
            a = a_part[k] if k < len(a_part) else None
            b = b_part[k] if k < len(b_part) else None
            cls_a = "l del" if a is not None and b is None else "l chg" if a is not None else "l"
            cls_b = "r add" if b is not None and a is None else "r chg" if b is not None else "r"
            rows.append(f'<tr><td class="{cls_a}">{esc(a or "")}</td>'
                        f'<td class="{cls_b}">{esc(b or "")}</td></tr>')
    head = ("<thead><tr><th>the model's S</th><th>ground truth (keys S has)</th></tr></thead>")
    return (f'<div class="scroll"><table class="spec-diff">{head}<tbody>{"".join(rows)}</tbody>'
            "</table></div>", changed)
