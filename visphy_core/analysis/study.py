"""`analyse`: every table and figure a study needs, from finished runs, written to one folder.

A study (``conf/experiment/<name>.yaml``) names what matters: the leaderboard always, and per
study the comparisons it exists for (the cross-engine test its Spearman matrices, the retry
ablation its success table, …). ``study=None`` produces everything the data supports. Each table
is written as ``<name>.csv``, ``.md`` and ``.tex``, each figure as ``.png`` and ``.svg``; the
folder also gets ``analysis.md`` (every table in one document, figures linked) and
``analysis.json`` (an index: runs, tables, figures, notes).

Numbers computed over fewer than `small_sample.MIN_SCENES` common scenes (Spearman ρ, bootstrap
intervals, judge agreement) carry a warning in the Markdown and LaTeX tables and a
``small_sample`` flag in ``analysis.json`` (`visphy_core.analysis.small_sample`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from visphy_core.analysis import (
    breakdown,
    correlation,
    figures,
    leaderboard,
    params,
    retry,
    small_sample,
)
from visphy_core.analysis.bootstrap import RESAMPLES, SEED, bootstrap_table
from visphy_core.analysis.column_views import (
    MODEL_SUCCESS,
    VIEWS,
    has_values,
    pick_columns,
    score_columns,
    unavailable_reason,
)
from visphy_core.analysis.export import to_markdown, write_table
from visphy_core.analysis.human import summarise_ratings
from visphy_core.analysis.load import label_runs
from visphy_core.infra.errors import UserError
from visphy_core.results.columns import JUDGE_PREFIX
from visphy_core.results.load import RunData

#: What each study produces (besides the runs table and the leaderboard, always there).
STUDIES: dict[str, tuple[str, ...]] = {
    "leaderboard": ("failures", "difficulty", "bootstrap", "human", "judges", "boxplots",
                    "radar"),
    "cross_engine": ("failures", "spearman", "bootstrap", "boxplots", "radar"),
    "judge_replacement": ("judges", "human", "failures"),
    "no_detection": ("failures", "bootstrap", "difficulty", "boxplots"),
    "forecast_only": ("failures", "bootstrap", "difficulty", "boxplots"),
    "retry_ablation": ("retry", "failures", "bootstrap"),
    "param_recovery": ("params", "failures"),
    "baselines": ("failures", "bootstrap", "difficulty", "boxplots", "radar"),
}
PARTS = ("failures", "difficulty", "bootstrap", "spearman", "human", "judges", "params", "retry",
         "boxplots", "radar")

TITLES = {
    "runs": "Runs compared",
    "leaderboard": "Leaderboard (headline metrics)",
    "leaderboard_all": "Leaderboard (every metric column)",
    "failures": "Failures by class",
    "difficulty": "Breakdown by difficulty and dimension",
    "bootstrap": "Paired bootstrap 95% CIs over common scenes (A − B)",
    "spearman": "Scene-level Spearman ρ between runs (long form)",
    "spearman_mean": "Mean off-diagonal Spearman ρ per metric",
    "judges": "Agreement between judges (and humans)",
    "human": "Human ratings",
    "param_recovery": "Parameter recovery (MAE)",
    "param_reference": "The paper's parameter table beside visphy's parameter columns",
    "retry": "Success at the first attempt and after one retry",
    "radar": "Radar values (each metric scaled 0.2..1 across runs: 0.2 = worst, 1 = best)",
}


@dataclass
class StudyOutputs:
    """What `analyse` made: the tables by name, the figures by name (PNG and SVG paths), every
    file written, and the Markdown document (also in ``analysis.md``)."""

    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    figures: dict[str, list[Path]] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    markdown: str = ""
    #: per table with numbers over fewer than `small_sample.MIN_SCENES` common scenes, the
    #: boolean mask of those cells
    marks: dict[str, pd.DataFrame] = field(default_factory=dict)


def _applicable(runs: list[RunData], columns: list[str]) -> tuple[str, ...]:
    """The parts the data supports (``study=None``)."""
    parts = ["failures", "difficulty", "boxplots"]
    if len(runs) >= 2:
        parts += ["bootstrap", "spearman", "radar"]
    if any(len(r.ratings) for r in runs):
        parts.append("human")
    judges = [c for c in score_columns(runs) if c.startswith(JUDGE_PREFIX) and has_values(runs, c)]
    if len(judges) >= 2 or (judges and "human" in parts):
        parts.append("judges")
    if params.param_columns([c for c in score_columns(runs) if has_values(runs, c)]):
        parts.append("params")
    if any(_retry_matters(r) for r in runs):
        parts.append("retry")
    return tuple(p for p in PARTS if p in parts)


def _retry_matters(run: RunData) -> bool:
    df = run.table
    retry_off = (run.config.get("run") or {}).get("retry") is False
    return retry_off or (len(df) > 0 and df["first_failure_class"].notna().any())


def _runs_table(runs: list[RunData], labels: list[str]) -> pd.DataFrame:
    return pd.DataFrame([{"run": label, "model": r.model, "engine": r.engine,
                          "dataset": str((r.config.get("dataset") or {}).get("name") or ""),
                          "scenes": len(r.results), "status": r.summary.get("status", ""),
                          "run_dir": str(r.run_dir)} for r, label in zip(runs, labels)])


def _human_table(runs: list[RunData], labels: list[str]) -> pd.DataFrame:
    rows = [{"run": label, **summarise_ratings(r.ratings)} for r, label in zip(runs, labels)]
    pooled = [r.ratings.assign(item=r.run_dir.name + "/" + r.ratings["item"],
                               scene_id=r.run_dir.name + "/" + r.ratings["scene_id"])
              for r in runs if len(r.ratings)]
    if len(pooled) > 1:
        rows.append({"run": "all runs", **summarise_ratings(pd.concat(pooled))})
    table = pd.DataFrame(rows).rename(columns={"mean": "human ↑", "n": "ratings",
                                               "alpha": "α (ordinal)"})
    return table


def _notes(runs: list[RunData], columns: list[str], view: str) -> list[str]:
    notes = [f"Means are over the model's own successes (view `{view}`) unless a column says "
             "`+fb` (fallback clips scored too); every mean has its count."
             if view == MODEL_SUCCESS else
             f"Scene values are taken in view `{view}` (fallback clips scored too)."]
    for col in columns:
        reason = unavailable_reason(runs, col)
        if reason and not has_values(runs, col):
            notes.append(f"`{col}` unavailable: {reason}")
    return notes


def below_power(runs: list[RunData], table: pd.DataFrame) -> list[str]:
    """One warning per pair of runs whose headline means differ by less than the validity
    study's discriminative power on their common scenes (`visphy_core.api.validity.power_at`):
    a difference the headline's own noise between equally right drawings can make."""
    from visphy_core.api.validity import power_at

    metric = next((str((r.summary.get("headline") or {}).get("metric") or "") for r in runs
                   if (r.summary.get("headline") or {}).get("metric")), "")
    if not metric or table.empty:
        return []
    out = []
    for row in table[table["metric"].astype(str).str.split().str[0] == metric].itertuples(
            index=False):
        n, diff = int(row[3]), float(row[6])
        power = power_at(n)
        if power is not None and np.isfinite(diff) and abs(diff) < power:
            out.append(f"`{row[1]}` − `{row[2]}` on `{metric}`: {diff:+.3f} over {n} scenes, "
                       f"below the {power:.3f} the validity study finds separable on {n} "
                       "scenes (docs/reference/validity.md): read it as a tie.")
    return out


def _tables(runs: list[RunData], labels: list[str], parts, columns: list[str],
            all_columns: list[str], view: str, resamples: int, seed: int,
            notes: list[str]) -> dict[str, pd.DataFrame]:
    """The study's tables, by name, for the ``parts`` that apply (a note is added to ``notes``
    for each comparison below the power the validity study finds)."""
    tables: dict[str, pd.DataFrame] = {"runs": _runs_table(runs, labels)}
    full = leaderboard.leaderboard(runs, labels, all_columns)
    tables["leaderboard"] = full[leaderboard.printed_columns(full, runs, columns)]
    tables["leaderboard_all"] = full
    if "failures" in parts:
        tables["failures"] = breakdown.failure_table(runs, labels)
    if "difficulty" in parts:
        tables["difficulty"] = breakdown.difficulty_table(runs, labels, columns, view)
    if "bootstrap" in parts and len(runs) >= 2:
        tables["bootstrap"] = bootstrap_table(runs, labels, columns, view, resamples, seed)
        notes += below_power(runs, tables["bootstrap"])
    if "spearman" in parts and len(runs) >= 2:
        long = correlation.spearman_long(runs, labels, columns, view)
        tables["spearman"] = long
        tables["spearman_mean"] = correlation.mean_offdiagonal(long)
        for col in columns:
            tables[f"spearman_{col}"] = correlation.spearman_matrix(long, labels, col)
    if "human" in parts and any(len(r.ratings) for r in runs):
        tables["human"] = _human_table(runs, labels)
    if "judges" in parts:
        judges = [c for c in all_columns if c.startswith(JUDGE_PREFIX) and has_values(runs, c)]
        if judges:
            tables["judges"] = correlation.judge_agreement(runs, judges)
    if "params" in parts:
        tables["param_recovery"] = params.param_table(runs, labels, all_columns, view)
        tables["param_reference"] = params.reference_table()
    if "retry" in parts:
        tables["retry"] = retry.retry_table(runs, labels)
    return tables


def analyse(runs: list[RunData], out_dir: Path, study: str | None = None,
            metrics: list[str] | None = None, *, view: str = MODEL_SUCCESS,
            resamples: int = RESAMPLES, seed: int = SEED) -> StudyOutputs:
    """Compute and write the study's tables and figures under ``out_dir``.

    ``metrics``: the score columns to compare (default: the headline subset, see
    `visphy_core.analysis.column_views.HEADLINE`; ``leaderboard_all`` always carries every column).
    ``view``: ``model_success`` (default) or ``with_fallbacks``, the scenes each comparison uses.
    A study name that is not one of `STUDIES` gets everything that applies, with a note.
    """
    if not runs:
        raise UserError("no runs to analyse")
    if view not in VIEWS:
        raise UserError(f"unknown view {view!r} (one of {', '.join(VIEWS)})")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    labels = label_runs(runs)
    for run, label in zip(runs, labels):
        run._label = label
    columns = pick_columns(runs, metrics)
    all_columns = score_columns(runs)
    notes = _notes(runs, columns, view)
    if study is None or study not in STUDIES:
        parts = _applicable(runs, columns)
        if study is not None:
            notes.append(f"study `{study}` is not one of {', '.join(STUDIES)}: every table the "
                         "data supports was made")
    else:
        parts = STUDIES[study]

    tables = _tables(runs, labels, parts, columns, all_columns, view, resamples, seed,
                     notes)

    marks = small_sample.marks(tables)
    if marks:
        notes.append(f"{small_sample.MARK} marks a number computed over fewer than "
                     f"{small_sample.MIN_SCENES} common scenes (tables: {', '.join(marks)}): "
                     "too few to rely on; its n is given beside it.")
    outputs = StudyOutputs(tables=tables, marks=marks)
    for name, table in tables.items():
        outputs.files += write_table(table, out_dir, name, caption=_title(name),
                                     marks=marks.get(name))
    if "boxplots" in parts:
        for col in columns:
            paths = figures.boxplot(runs, labels, col, out_dir, view)
            if paths:
                outputs.figures[f"boxplot_{col}"] = paths
    if "radar" in parts:
        radar = figures.radar_table(runs, labels, columns, view)
        paths = figures.radar(radar, out_dir)
        if paths:
            outputs.figures["radar"] = paths
            tables["radar"] = radar
            outputs.files += write_table(radar, out_dir, "radar", caption=_title("radar"))
    for paths in outputs.figures.values():
        outputs.files += paths
    outputs.markdown = _markdown(study, view, tables, outputs.figures, notes, out_dir, marks)
    md_path, index_path = out_dir / "analysis.md", out_dir / "analysis.json"
    md_path.write_text(outputs.markdown)
    index = {"study": study, "view": view, "metrics": columns, "parts": list(parts),
             "runs": [{"label": label, "run_dir": str(r.run_dir)}
                      for r, label in zip(runs, labels)],
             "tables": {name: {"title": _title(name), "rows": int(len(t)),
                               "files": [f"{name}.{e}" for e in ("csv", "md", "tex")],
                               **({"small_sample": small_sample.flags(t, marks[name], name)}
                                  if name in marks else {})}
                        for name, t in tables.items()},
             "small_sample": {"min_scenes": small_sample.MIN_SCENES,
                              "flagged": {name: int(m.to_numpy().any(axis=1).sum())
                                          for name, m in marks.items()}},
             "figures": {name: [p.name for p in paths]
                         for name, paths in outputs.figures.items()},
             "notes": notes}
    index_path.write_text(json.dumps(index, indent=1, ensure_ascii=False))
    outputs.files += [md_path, index_path]
    return outputs


def _transposed(table: pd.DataFrame) -> pd.DataFrame:
    body = table.set_index("run").T.astype(object)
    body.index.name = "column"
    return body.reset_index()


def _title(name: str) -> str:
    if name.startswith("spearman_") and name not in TITLES:
        return f"Scene-level Spearman ρ between runs: {name[len('spearman_'):]}"
    return TITLES.get(name, name)


def _markdown(study: str | None, view: str, tables: dict[str, pd.DataFrame],
              figs: dict[str, list[Path]], notes: list[str], out_dir: Path,
              marks: dict[str, pd.DataFrame] | None = None) -> str:
    marks = marks or {}
    parts = [f"# Analysis: {study or 'all applicable tables'}", ""]
    parts += [f"- {n}" for n in notes] + [""]
    for name, table in tables.items():
        parts += [f"## {_title(name)}", "", f"`{name}.csv` · `{name}.md` · `{name}.tex`", ""]
        if name == "leaderboard_all":   # hundreds of columns: one row per column reads better
            parts += ["(transposed here: one row per column, one column per run)", "",
                      to_markdown(_transposed(table))]
        else:
            parts.append(to_markdown(table, marks.get(name)))
    if figs:
        parts += ["## Figures", ""]
        for name, paths in figs.items():
            png = next((p for p in paths if p.suffix == ".png"), paths[0])
            parts += [f"![{name}]({png.relative_to(out_dir).as_posix()})", ""]
    return "\n".join(parts)

