"""Tables and figures for a paper, computed from finished run directories.

Entry points: `visphy_core.analysis.load.load_runs` (run directories or folders of them →
`RunData`, labelled for comparison) and `visphy_core.analysis.study.analyse` (→ `StudyOutputs`:
every table as CSV/Markdown/LaTeX, every figure as PNG/SVG, ``analysis.md`` and
``analysis.json``); on the command line ``python -m visphy_core analyse PATH...``.

One concern per module: `load` (runs and labels), `columns` (score columns, directions, the two
success views), `leaderboard`, `bootstrap` (paired CIs), `correlation` (Spearman between runs,
agreement between judges), `human` and `agreement` (ratings, Krippendorff's alpha),
`breakdown` (difficulty, failure classes), `params` (parameter recovery), `retry`, `figures`
(boxplots, radar), `export` (CSV/Markdown/LaTeX), `printing` (rich tables), `study`.
Nothing is imported here, so importing one module stays cheap.
"""
