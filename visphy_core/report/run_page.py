"""The run report's page: header, leaderboard (first), counts, the scene list with its filters,
then one section per scene (`visphy_core.report.scene_section`)."""

from __future__ import annotations

from visphy_core.report.column_groups import HEADINGS, PRIMARY, direction_of, grouped, label
from visphy_core.report.markup import arrow, attr, details, esc, fmt, rate, table
from visphy_core.report.plots import family_bars, headline_plot
from visphy_core.report.scene_section import SceneView, anchor, outcome_of
from visphy_core.results.layout import RESULTS_JSONL, SUMMARY
from visphy_core.results.load import RunData

#: Primary score columns shown in the scene list.
LIST_COLUMNS = 3


def _mode(run: RunData) -> str:
    frames = run.cfg("prompt.frames")
    parts = [f"frames {','.join(str(f) for f in frames)}" if frames else None,
             "detection" if run.cfg("prompt.detection", True) else "no detection",
             "forecast-only" if run.cfg("prompt.forecast_only") else None,
             "timed" if run.cfg("prompt.timed") else None,
             "retry" if run.cfg("run.retry", True) else "no retry"]
    return ", ".join(p for p in parts if p)


def _isolation(run: RunData) -> str:
    levels = run.manifest.get("isolation") or run.summary.get("isolation_levels") or {}
    used = run.summary.get("isolation") or sorted({r.isolation for r in run.results
                                                   if r.isolation})
    text = "; ".join(f"{k}: {v}" for k, v in levels.items()) if isinstance(levels, dict) else ""
    if used:
        text += (" · " if text else "") + "programs ran under " + ", ".join(map(str, used))
    return text or "unknown"


def header(run: RunData) -> str:
    s, m = run.summary, run.manifest
    model = (m.get("model") or {}) if isinstance(m.get("model"), dict) else {}
    model_name = s.get("model") or run.cfg("model.name") or model.get("name") or "?"
    model_text = str(model_name) + (f" ({model['model_id']})" if model.get("model_id") else "")
    dataset = " ".join(str(x) for x in (run.cfg("dataset.name") or s.get("dataset"),
                                       f"split {run.cfg('dataset.split')}"
                                       if run.cfg("dataset.split") else None) if x)
    n_sel = s.get("n_selected") or len(m.get("scenes") or []) or len(run.results)
    chash = str(s.get("config_hash") or m.get("config_hash") or "?")
    started, ended = m.get("started"), m.get("ended")
    when = f"{started or '?'}" + (f" → {ended}" if ended else "")
    status = run.status
    cls = "good" if status == "finished" else "bad"
    items = [("model", model_text), ("engine", run.cfg("engine.name") or s.get("engine")),
             ("dataset", f"{dataset} ({n_sel} scenes selected)"),
             ("prompt", ", ".join(s.get("prompt_versions") or []) or "?"),
             ("mode", _mode(run)), ("config hash", chash[:12]),
             ("isolation", _isolation(run)), ("date", when),
             ("visphy", m.get("visphy_version")),
             ("judges", ", ".join(m.get("judges") or []) or "none")]
    meta = "".join(f"<span>{esc(k)}: <b>{esc(v)}</b></span>" for k, v in items if v)
    notes = [f'<p class="note warn">{esc(run.summary_source)}</p>'] \
        if run.summary_source != SUMMARY else []
    if run.skipped_lines:
        notes.append(f'<p class="note warn">{run.skipped_lines} line(s) of {RESULTS_JSONL} could '
                     "not be read (a half-written last line of a killed run)</p>")
    if run.pending:
        notes.append(f'<p class="note warn">{len(run.pending)} selected scene(s) have no '
                     "result (the run stopped before them)</p>")
    if s.get("error"):
        notes.append(f'<p class="note bad">error: {esc(s["error"])}</p>')
    if (s.get("cost_cap") or {}).get("message"):
        notes.append(f'<p class="note warn">{esc(s["cost_cap"]["message"])}</p>')
    return (f'<header class="top"><h1>visphy run {esc(run.name)} '
            f'<span class="badge {cls}" id="run-status">{esc(status)}</span></h1>'
            f'<div class="meta">{meta}</div>{"".join(notes)}</header>')


def _mean_cell(info: dict, which: str) -> str:
    mean, n = info.get(f"mean_{which}"), info.get(f"n_{which}") or 0
    if mean is None:
        if info.get("unavailable"):
            return f'<span class="unavailable">unavailable: {esc(info["unavailable"])}</span>'
        return '<span class="note">— (n=0)</span>'
    return f"{esc(fmt(mean))} <span class=\"note\">(n={int(n)})</span>"


def leaderboard(run: RunData) -> str:
    """The run's metric means in both success views, with their counts and directions."""
    metrics = run.summary.get("metrics") or {}
    s = run.summary
    intro = (f'<p class="note">means over the model\'s successes '
             f'({s.get("model_success", 0)} scene(s)) and over every scored scene with the '
             f'fallback clips ({s.get("system_success", 0)}); ↑ higher is better, ↓ lower</p>')

    def rows(members: list[str]) -> list[list[str]]:
        return [[f"{esc(label(c))}{arrow(direction_of(c, s))}",
                 _mean_cell(metrics[c], "model_success"),
                 _mean_cell(metrics[c], "with_fallbacks")] for c in members]

    heads = ["metric", "model successes", "with fallbacks"]
    main, folded = [], []
    folded_keys: list[str] = []
    for key, members in grouped(list(metrics)):
        block = table(heads, rows(members), cls="leaderboard", attrs=f" data-group={attr(key)}")
        if key in PRIMARY:
            main.append(block)
        else:
            folded.append(f'<p class="note">{esc(HEADINGS[key])}</p>{block}')
            folded_keys.append(key)
    head = s.get("headline") or {}
    if head.get("metric"):
        ci = head.get("ci")
        interval = f" [{esc(fmt(ci[0]))}, {esc(fmt(ci[1]))}]" if ci else ""
        small = " · fewer than 10 scenes: read the interval" if head.get("small_sample") else ""
        card = _card(f"headline {head['metric']} ↑ (95% bootstrap interval, "
                     f"n={head.get('n', 0)}; a still clip scores 0, the ground truth about "
                     f"1{small})", f"{esc(fmt(head.get('mean')))}{interval}")
        main.insert(0, f'<div class="cards" id="headline">{card}</div>')
    plots = headline_plot(s, run.cfg("metrics.headline.clip")) + family_bars(s)
    if not metrics:
        main.append('<p class="note">no scores yet</p>')
    else:
        first = 1 if head.get("metric") else 0
        main[first:] = [f'<div class="board"><div>{"".join(main[first:])}</div>'
                        f'<div class="board-plots" id="run-plots">{plots}</div></div>']
    if folded:
        shown = ", ".join(dict.fromkeys(FOLDED_NAMES.get(k, k) for k in folded_keys))
        main.append(details(f"other pairings and tracks ({shown})", "".join(folded)))
    return f'<section id="leaderboard"><h2>Leaderboard</h2>{intro}{"".join(main)}</section>'


#: The folded groups' short names in the expander's title (only the groups the run has).
FOLDED_NAMES = {"aligned": "aligned", "paper": "paper protocol", "align": "alignment",
                "spec": "spec track", "norm": "variance-normalised"}


def _card(key: str, value: str, ident: str = "") -> str:
    ident_attr = f" id={attr(ident)}" if ident else ""
    return (f'<div class="card"{ident_attr}><div class="v">{value}</div>'
            f'<div class="k">{esc(key)}</div></div>')


def counts(run: RunData) -> str:
    s = run.summary
    n = s.get("n_scenes", len(run.results))
    model = run.manifest.get("model") or {}
    own = ("baseline clips made (no model: the baseline's own clip)" if model.get("baseline")
           else "model success (the model's own clip)" if model.get("output") == "video"
           else "model success (the model's own program)")
    cards = [
        _card(own,
              esc(rate(s.get("model_success"), n)), "count-model-success"),
        _card("model success, evaluable scenes",
              esc(rate(s.get("model_success"), s.get("n_evaluable")))),
        _card("system success (fallbacks counted)", esc(rate(s.get("system_success"), n)),
              "count-system-success"),
        _card("fallback clips", esc(s.get("fallbacks", 0)), "count-fallbacks"),
        _card("repaired (success on the retry)", esc(s.get("repaired", 0)), "count-repaired"),
        _card("infra retries", esc(s.get("infra_retries", 0)))]
    spec = s.get("spec") or {}
    if spec:
        cards.append(_card("spec S valid / invalid / absent",
                           esc(f"{spec.get('valid', 0)} / {spec.get('invalid', 0)} / "
                               f"{spec.get('absent', 0)}")))
    cost = ((s.get("usage") or {}).get("all") or {}).get("cost_usd")
    if cost is not None:
        cards.append(_card("cost (USD)", esc(f"{cost:.4f}")))
    failures = s.get("failures") or {}
    rows = [[esc(cls), esc("the model's" if side == "model" else "infrastructure or data"),
             f'<span class="fail-count">{int(k)}</span>']
            for side in ("model", "infra_or_data")
            for cls, k in sorted((failures.get(side) or {}).items())]
    fail = (table(["failure class", "whose", "scenes"], rows, cls="failures",
                  attrs=' id="failures"') if rows
            else '<p class="note" id="failures">no failures</p>')
    flags = s.get("flags") or {}
    flag_text = (f'<p class="note">flags: {esc(", ".join(f"{k}: {v}" for k, v in flags.items()))}'
                 "</p>" if flags else "")
    judges = s.get("judges") or {}
    judge_rows = [[esc(k), esc(fmt(v.get("mean"))), esc(v.get("n_valid", 0)),
                   esc(v.get("n_invalid", 0)),
                   esc("; ".join(f"{r}: {c}" for r, c in (v.get("invalid") or {}).items()))]
                  for k, v in judges.items() if isinstance(v, dict)]
    judge_table = ("<h3>Judges</h3>" + table(["judge", "mean score", "valid", "invalid", "why"],
                                              judge_rows)) if judge_rows else ""
    return (f'<section id="counts"><h2>Success and failures</h2><div class="cards">'
            f'{"".join(cards)}</div>{fail}{flag_text}{judge_table}</section>')


def _outcome_label(view: SceneView) -> str:
    r = view.result
    if r is None:
        return '<span class="warn">not finished</span>'
    if r.model_success:
        return '<span class="good">' + ("repaired" if r.attempts > 1 else "success") + "</span>"
    fb = " (fallback)" if r.fallback else ""
    return f'<span class="bad">{esc(r.failure_class or "failed")}{fb}</span>'


def scene_list(run: RunData, views: list[SceneView]) -> str:
    """The table of contents, filterable by outcome and difficulty."""
    metrics = run.summary.get("metrics") or {}
    shown = [c for key, members in grouped(list(metrics)) if key in PRIMARY
             for c in members][:LIST_COLUMNS]
    rows = []
    for v in views:
        r = v.result
        cells = [f'<a href="#{anchor(v.scene_id)}">{esc(v.scene_id)}</a>',
                 esc(r.dim if r else ""), esc((r.difficulty if r else None) or ""),
                 _outcome_label(v), esc(r.attempts if r else "")]
        cells += [esc(fmt(r.scores.get(c))) if r else "" for c in shown]
        rows.append(f'<tr data-outcome={attr(outcome_of(r))} '
                    f'data-difficulty={attr((r.difficulty if r else None) or "")}>'
                    + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    heads = ["scene", "dim", "difficulty", "outcome", "attempts"] + [
        f"{esc(label(c))}{arrow(direction_of(c, run.summary))}" for c in shown]
    outcomes = sorted({outcome_of(v.result) for v in views})
    levels = sorted({(v.result.difficulty or "") for v in views if v.result} - {""})

    def select(ident: str, name: str, values: list[str]) -> str:
        opts = "".join(f"<option value={attr(x)}>{esc(x)}</option>" for x in values)
        return (f"<label>{esc(name)} <select id={attr(ident)}><option value=\"\">all</option>"
                f"{opts}</select></label>")

    filters = (f'<div class="filters">{select("filter-outcome", "outcome", outcomes)}'
               f'{select("filter-difficulty", "difficulty", levels)}'
               '<span id="filter-count" class="note"></span></div>')
    head = "".join(f"<th>{h}</th>" for h in heads)
    return (f'<section id="scenes"><h2>Scenes</h2>{filters}<table class="scene-list">'
            f'<thead><tr>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table></section>')
