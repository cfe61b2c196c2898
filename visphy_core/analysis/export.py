"""Tables as files a paper can take: CSV (full precision), Markdown and LaTeX (booktabs).

Markdown and LaTeX show numbers with 4 significant digits (integers as integers, rates and
coefficients alike), a missing value as an em dash, and keep the direction arrows of headers
(LaTeX: ``$\\uparrow$``). Written here rather than through pandas' ``to_markdown`` so the
output needs no optional dependency and is identical everywhere.

``marks`` (a boolean frame shaped like the table, from
`visphy_core.analysis.small_sample.marks`) puts a warning beside the marked numbers: ``⚠`` in
Markdown, ``$^{\\dagger}$`` in LaTeX, with a legend under the table (LaTeX: in the caption).
The CSV keeps the plain numbers.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from visphy_core.analysis.figures import safe_name
from visphy_core.infra.numbers import number

MISSING = "—"
LATEX_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
                 "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
                 "^": r"\textasciicircum{}"}
LATEX_SYMBOLS = {"↑": r"$\uparrow$", "↓": r"$\downarrow$", "ρ": r"$\rho$", "α": r"$\alpha$",
                 "μ": r"$\mu$", "−": "--", "²": r"$^2$", "Δ": r"$\Delta$", "…": r"\ldots{}",
                 "—": "---", "→": r"$\rightarrow$"}


def fmt(value) -> str:
    """One cell as text."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return MISSING
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if math.isinf(v):
            return "∞" if v > 0 else "-∞"
        return number(v)
    return str(value)


def _marked(marks: pd.DataFrame | None, df: pd.DataFrame):
    """Per row, per column: whether the cell carries the small-sample warning."""
    if marks is None:
        return [[False] * len(df.columns) for _ in range(len(df))]
    m = marks.reindex(index=df.index, columns=df.columns, fill_value=False)
    return m.fillna(False).astype(bool).to_numpy().tolist()


def to_markdown(df: pd.DataFrame, marks: pd.DataFrame | None = None) -> str:
    """A GitHub-flavoured Markdown table (numbers right-aligned); cells ``marks`` flags get the
    small-sample warning beside them, and the table its legend."""
    from visphy_core.analysis.small_sample import LEGEND, MARK

    def cell(text: str) -> str:
        return text.replace("|", "\\|").replace("\n", " ")

    heads = [cell(str(c)) for c in df.columns]
    numeric = [pd.api.types.is_numeric_dtype(df[c]) and not pd.api.types.is_bool_dtype(df[c])
               for c in df.columns]
    lines = ["| " + " | ".join(heads) + " |",
             "|" + "|".join("---:" if n else ":---" for n in numeric) + "|"]
    flagged = _marked(marks, df)
    for row, flags in zip(df.itertuples(index=False), flagged):
        lines.append("| " + " | ".join(cell(fmt(v)) + (f" {MARK}" if f else "")
                                       for v, f in zip(row, flags)) + " |")
    if any(any(f) for f in flagged):
        lines += ["", LEGEND]
    return "\n".join(lines) + "\n"


def latex_number(text: str) -> str:
    """``3.692e-06`` as ``$3.692\\times10^{-6}$``; anything else unchanged."""
    match = re.fullmatch(r"(-?[0-9.]+)e([+-])0*([0-9]+)", text)
    if not match:
        return text
    mantissa, sign, exponent = match.groups()
    return rf"${mantissa}\times10^{{{'-' if sign == '-' else ''}{exponent}}}$"


def latex_escape(text: str) -> str:
    out = "".join(LATEX_SPECIAL.get(ch, ch) for ch in text)
    for symbol, tex in LATEX_SYMBOLS.items():
        out = out.replace(symbol, tex)
    return out


def to_latex(df: pd.DataFrame, caption: str | None = None,
             marks: pd.DataFrame | None = None) -> str:
    """A booktabs ``tabular`` (inside a ``table`` with a caption when one is given); cells
    ``marks`` flags get a dagger and the caption (or a line under the table) its legend."""
    from visphy_core.analysis.small_sample import LATEX_LEGEND, LATEX_MARK

    numeric = [pd.api.types.is_numeric_dtype(df[c]) and not pd.api.types.is_bool_dtype(df[c])
               for c in df.columns]
    spec = "".join("r" if n else "l" for n in numeric)
    lines = [rf"\begin{{tabular}}{{{spec}}}", r"\toprule",
             " & ".join(latex_escape(str(c)) for c in df.columns) + r" \\", r"\midrule"]
    flagged = _marked(marks, df)
    for row, flags in zip(df.itertuples(index=False), flagged):
        lines.append(" & ".join(latex_number(latex_escape(fmt(v))) + (LATEX_MARK if f else "")
                                for v, f in zip(row, flags)) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    legend = LATEX_LEGEND if any(any(f) for f in flagged) else ""
    if caption:
        text = latex_escape(caption) + (f" ({legend.rstrip('.')})" if legend else "")
        lines = [r"\begin{table}[t]", r"\centering", *lines, rf"\caption{{{text}}}",
                 r"\end{table}"]
    elif legend:
        lines.append(rf"\par{{\footnotesize {legend}}}")
    return "\n".join(lines) + "\n"


def write_table(df: pd.DataFrame, out_dir: Path, name: str,
                caption: str | None = None, marks: pd.DataFrame | None = None) -> list[Path]:
    """``<name>.csv``, ``<name>.md`` and ``<name>.tex`` under ``out_dir`` (``marks``: the
    small-sample warnings of the Markdown and LaTeX versions)."""
    base = out_dir / safe_name(name)
    csv, md, tex = (base.with_name(base.name + ext) for ext in (".csv", ".md", ".tex"))
    df.to_csv(csv, index=False)
    md.write_text(to_markdown(df, marks))
    tex.write_text(to_latex(df, caption, marks))
    return [csv, md, tex]
