"""One scene of a run report: the clips side by side under one control, what the model saw and
wrote, how it was scored and judged, and why it failed when it did.

Every text that comes from the model, the judge or the program's run (replies, programs, specs,
logs, failure details) is escaped; a scene directory may hold any subset of its files (a failed
or interrupted scene, a pixel-space model without a program, a run without a spec).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from visphy_core.report.column_groups import HEADINGS, PRIMARY, direction_of, grouped, label
from visphy_core.report.frame_data import FrameData
from visphy_core.report.locate_truth import GroundTruth
from visphy_core.report.markup import arrow, attr, details, esc, fmt, pre, table, url
from visphy_core.report.media import MediaStore, Placed, clip_timing
from visphy_core.report.scene_plots import scene_plots
from visphy_core.report.spec_diff import diff_table
from visphy_core.results import layout
from visphy_core.results.row import NOT_EVALUABLE, SceneResult

#: Untrusted texts longer than this are cut in the page (the file keeps everything).
MAX_TEXT = 200_000


@dataclass
class SceneView:
    """What a scene section is made from."""

    scene_id: str
    result: SceneResult | None      # None: the run never finished this scene
    scene_dir: Path
    truth: GroundTruth
    summary: dict
    #: ``preload`` of the scene's clips: ``metadata`` in long reports (each clip loads when
    #: played or scrubbed), ``auto`` otherwise.
    preload: str = "auto"


def safe_name(scene_id: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", scene_id) or "scene"


def anchor(scene_id: str) -> str:
    return "scene-" + safe_name(scene_id)


def outcome_of(result: SceneResult | None) -> str:
    """The value a scene is filtered by: ``success``, its failure class, or ``not_run``."""
    if result is None:
        return "not_run"
    if result.model_success:
        return "success"
    return result.failure_class or "unknown"


def _read(path: Path) -> str | None:
    if not path.is_file():
        return None
    text = path.read_bytes()[:MAX_TEXT + 1].decode("utf-8", errors="replace")
    if len(text) > MAX_TEXT:
        text = text[:MAX_TEXT] + f"\n… (cut at {MAX_TEXT} characters; the file is {path})"
    return text


def _json(path: Path) -> Any:
    text = _read(path)
    if text is None:
        return None
    try:
        return json.loads(text)
    except ValueError:
        return None


def _attempt_of(path: Path) -> int:
    match = re.search(r"\.attempt(\d+)\.", path.name)
    return int(match.group(1)) if match else 1


def badges(view: SceneView) -> str:
    r = view.result
    out = []
    if r is None:
        return '<span class="badge warn">not finished</span>'
    out.append(f'<span class="badge">{esc(r.dim)}</span>')
    if r.difficulty:
        out.append(f'<span class="badge">{esc(r.difficulty)}</span>')
    if r.model_success:
        text = "repaired" if r.attempts > 1 else "model success"
        out.append(f'<span class="badge ok">{text}</span>')
    else:
        kind = "warn" if r.failure_class in NOT_EVALUABLE else "fail"
        out.append(f'<span class="badge {kind}">{esc(r.failure_class or "failed")}</span>')
    if r.fallback:
        out.append('<span class="badge warn">fallback clip</span>')
    out += [f'<span class="badge warn">{esc(f)}</span>' for f in r.flags]
    return "".join(out)


def _outcome_text(r: SceneResult | None) -> str:
    if r is None:
        return ('<p class="warn">The run stopped before this scene finished: no row in '
                f"{layout.RESULTS_JSONL} (rerun the same command to resume).</p>")
    parts = [f"attempts: {r.attempts}"]
    if r.first_failure_class and r.attempts > 1:
        parts.append(f"first attempt failed: {esc(r.first_failure_class)}")
    if r.failure_class:
        parts.append(f'<span class="bad">failure: {esc(r.failure_class)}</span>')
    if r.fallback:
        parts.append("scored on the fallback clip (the first key frame held: nothing moves)")
    if r.isolation:
        parts.append(f"isolation: {esc(r.isolation)}")
    if r.render_wall_s is not None:
        parts.append(f"render {r.render_wall_s:.2f} s" + (" (cached)" if r.render_cached else ""))
    out = f'<p class="meta">{" · ".join(parts)}</p>'
    if r.failure_detail:
        out += f'<p class="text bad">{esc(r.failure_detail)}</p>'
    return out


# ------------------------------------------------------------------ clips


def clip_figure(title: str, placed: Placed, missing: str, preload: str = "metadata", *,
                prefix: str = "", controls: bool = False) -> str:
    """A clip as a captioned figure (``prefix``: from the page to the media store's folder;
    ``controls``: the browser's own, for a clip outside the report's shared player)."""
    if placed.rel is None:
        body = f'<div class="missing-clip">{esc(placed.error or missing)}</div>'
    else:
        shown = " controls" if controls else ""
        body = (f"<video muted loop playsinline{shown} preload={attr(preload)} "
                f"src={attr(url(prefix + placed.rel))}></video>")
    note = f'<p class="note">{esc(placed.note)}</p>' if placed.note else ""
    return f'<figure class="clip"><figcaption>{esc(title)}</figcaption>{body}{note}</figure>'


def _clip_contract(view: SceneView) -> tuple[float, int]:
    """fps and frame count the scrubber steps through: the scored clip's, else the ground
    truth's (a scene that never made a clip)."""
    meta = _json(view.scene_dir / layout.FRAMES_META) or {}
    try:
        fps, frames = float(meta.get("fps") or 0), int(meta.get("n_frames") or 0)
    except (TypeError, ValueError):
        fps, frames = 0.0, 0
    if (not fps or not frames) and view.truth.video is not None:
        fps, frames = clip_timing(view.truth.video)
    return fps, frames


def clips(view: SceneView, media: MediaStore) -> str:
    base = f"media/{safe_name(view.scene_id)}"
    d, r = view.scene_dir, view.result
    figures = [clip_figure("ground truth",
                           media.video(view.truth.video, f"{base}/ground_truth.mp4"),
                           view.truth.missing or "no ground-truth clip", view.preload)]
    generated_title = "generated (fallback clip)" if r is not None and r.fallback else "generated"
    figures.append(clip_figure(generated_title,
                               media.video(d / layout.VIDEO, f"{base}/generated.mp4"),
                               "no generated clip (the program produced none and no fallback "
                               "was rendered)", view.preload))
    if (d / layout.SPEC_VIDEO).is_file():
        figures.append(clip_figure("spec track (S simulated)",
                                   media.video(d / layout.SPEC_VIDEO, f"{base}/spec_track.mp4"),
                                   "", view.preload))
    reply = d / layout.attempt_file(layout.REPLY, 1, "mp4")
    if reply.is_file():
        figures.append(clip_figure("the model's own video (as returned, before normalisation)",
                                   media.video(reply, f"{base}/reply.mp4"), "",
                                   view.preload))
    for partial in sorted(d.glob(f"{layout.PARTIAL}*.mp4")):
        figures.append(clip_figure(f"partial clip of the failed attempt {_attempt_of(partial)}",
                                   media.video(partial, f"{base}/{partial.name}"), "",
                                   view.preload))
    fps, frames = _clip_contract(view)
    last = max(frames - 1, 0)
    controls = (
        '<div class="controls">'
        '<button type="button" data-act="play">▶ play</button>'
        '<button type="button" data-act="step" data-by="-1" title="previous frame">◀</button>'
        '<button type="button" data-act="step" data-by="1" title="next frame">▶</button>'
        f'<input type="range" min="0" max="{last}" step="1" value="0" aria-label="frame">'
        '<span class="frame-label"></span>'
        '<label>speed <select data-act="rate"><option value="0.25">¼×</option>'
        '<option value="0.5">½×</option><option value="1" selected>1×</option></select></label>'
        "</div>")
    return (f'<div class="sync" data-fps="{fps:g}" data-frames="{frames}">'
            f'<div class="clips">{"".join(figures)}</div>{controls}</div>')


def keyframes(view: SceneView, media: MediaStore) -> str:
    prompt = _json(view.scene_dir / layout.PROMPT) or {}
    names = [str(n) for n in prompt.get("images") or []]
    if not names:
        return ""
    base = f"media/{safe_name(view.scene_id)}"
    out = []
    for name in names:
        match = re.fullmatch(r"frame_(\d+)", name)
        index = int(match.group(1)) if match else None
        if index is None:
            out.append(f'<figure><div class="missing-clip">{esc(name)}</div></figure>')
            continue
        rel = f"{base}/key_frame_{index:02d}.png"
        if index in view.truth.keyframes:
            placed = media.image(view.truth.keyframes[index], rel)
        elif view.truth.video is not None:
            placed = media.frame_of(view.truth.video, index, rel)
        else:
            placed = Placed(None, error=view.truth.missing)
        body = (f'<img alt={attr(f"key frame {index}")} src={attr(url(placed.rel))}>'
                if placed.rel else f'<div class="missing-clip">{esc(placed.error)}</div>')
        out.append(f"<figure>{body}<figcaption>frame {index}</figcaption></figure>")
    return ("<h3>Key frames shown to the model</h3>"
            f'<div class="keyframes">{"".join(out)}</div>')


# ------------------------------------------------------------------ scores, judges, spec


def scores(view: SceneView) -> str:
    r = view.result
    if r is None:
        return ""
    columns = list(r.scores)
    columns += [c for c in r.unavailable if c not in columns]
    if not columns:
        return "<h3>Scores</h3><p class=\"note\">no scores (nothing was scored)</p>"

    def row(c: str) -> list[str]:
        value = r.scores.get(c)
        if value is None and c in r.unavailable:
            shown = f'<span class="unavailable">unavailable: {esc(r.unavailable[c])}</span>'
        else:
            shown = esc(fmt(value))
        return [f"{esc(label(c))}{arrow(direction_of(c, view.summary))}", shown]

    out = ["<h3>Scores</h3>"]
    folded = []
    for key, members in grouped(columns):
        block = (f'<p class="note">{esc(HEADINGS[key])}</p>'
                 + table(["score", "value"], [row(c) for c in members], cls="scores"))
        (out if key in PRIMARY else folded).append(block)
    if folded:
        out.append(details("other pairings and tracks", "".join(folded)))
    return "".join(out)


def verdicts(view: SceneView) -> str:
    data = _json(view.scene_dir / layout.VERDICTS)
    errors = view.result.judge_errors if view.result else {}
    if not isinstance(data, dict) and not errors:
        return ""
    out = ["<h3>Judges</h3>"]
    for key, v in (data or {}).items():
        v = v if isinstance(v, dict) else {}
        score = f"{fmt(v.get('score'))}/10" if v.get("valid") else \
            f'<span class="bad">invalid: {esc(v.get("error") or "no verdict")}</span>'
        who = " · ".join(esc(x) for x in (v.get("judge_model"), v.get("sampling")) if x)
        out.append(f'<div class="verdict"><b>{esc(key)}</b> {score}'
                   f' <span class="note">{who}</span>'
                   f'<p class="text">{esc(v.get("justification") or "")}</p>'
                   + (details("raw reply", pre(str(v.get("raw") or ""))) if v.get("raw") else "")
                   + "</div>")
    for key, why in errors.items():
        if not isinstance(data, dict) or key not in data:
            out.append(f'<div class="verdict"><b>{esc(key)}</b> '
                       f'<span class="bad">invalid: {esc(why)}</span></div>')
    return "".join(out)


def spec_section(view: SceneView) -> str:
    d = view.scene_dir
    specs = sorted(d.glob("spec*.json"), key=_attempt_of)
    specs = [p for p in specs if re.fullmatch(r"spec(\.attempt\d+)?\.json", p.name)]
    truth = _json(view.truth.spec) if view.truth.spec else None
    r = view.result
    if not specs:
        why = "the reply had no ```json spec block" if r is not None and r.spec_valid is None \
            else "no spec"
        gt = details("ground-truth spec", pre(json.dumps(truth, indent=1))) if truth else ""
        return f"<h3>Physical spec S</h3><p class=\"note\">{esc(why)}</p>{gt}"
    final = specs[-1]
    model = _json(final)
    out = ["<h3>Physical spec S vs ground truth</h3>"]
    validation = _json(d / final.name.replace("spec", "spec_validation", 1)) or {}
    problems = validation.get("problems") or []
    state = ("valid" if validation.get("valid") else "invalid") if validation else "unchecked"
    out.append(f'<p class="note">S ({esc(final.name)}) is {state} against the ground truth\'s '
               "schema" + (f": {esc('; '.join(str(p) for p in problems))}" if problems else "")
               + "</p>")
    if r is not None and r.spec_track:
        out.append(f'<p class="note">spec track: {esc(r.spec_track)}'
                   + (f" ({esc(r.spec_track_error)})" if r.spec_track_error else "") + "</p>")
    if model is not None and truth is not None:
        diff, changed = diff_table(model, truth)
        if changed:
            out.append(f'<p class="note">{changed} differing line(s); numbers to 4 significant '
                       "figures, keys sorted, bodies by id</p>" + diff)
        else:
            out.append('<p class="note good">S matches the ground truth on every key it has '
                       "(numbers to 4 significant figures)</p>")
    elif truth is None:
        out.append(f'<p class="note">no ground-truth spec to compare with '
                   f'({esc(view.truth.missing or "the dataset has none")})</p>')
    raw = "".join(details(f"S as written ({esc(p.name)})", pre(_read(p) or "")) for p in specs)
    if truth is not None:
        raw += details("ground-truth spec (complete)", pre(json.dumps(truth, indent=1)))
    return "".join(out) + raw


# ------------------------------------------------------------------ texts


def analysis(view: SceneView) -> str:
    d = view.scene_dir
    text = _read(d / layout.ANALYSIS)
    out = "<h3>The model's analysis A</h3>" + (
        f'<p class="text analysis">{esc(text)}</p>' if text is not None
        else '<p class="note">no analysis (the reply had none, or no reply)</p>')
    reference = _read(d / layout.REFERENCE)
    if reference is not None:
        out += details("reference description (what A is scored against)",
                       f'<p class="text">{esc(reference)}</p>')
    return out


def files(view: SceneView) -> str:
    d = view.scene_dir
    folded = []
    for path in sorted(d.glob(f"{layout.PROGRAM}*"), key=_attempt_of):
        text = _read(path) or ""
        folded.append(details(f"program, attempt {_attempt_of(path)} ({esc(path.name)}, "
                              f"{text.count(chr(10)) + 1} lines)", pre(text, "program")))
    for path in sorted(d.glob(f"{layout.RESPONSE}*.txt"), key=_attempt_of):
        meta = _json(path.with_suffix(".json")) or {}
        extra = "".join(f"<p class=\"note\">{esc(k)}: {esc(meta[k])}</p>"
                        for k in ("error", "error_kind", "finish_reason", "refusal", "model_id")
                        if meta.get(k))
        folded.append(details(f"reply, attempt {_attempt_of(path)} ({esc(path.name)})",
                              extra + pre(_read(path) or "", "reply")))
    for path in sorted(d.glob(f"{layout.RENDER_LOG}*.log"), key=_attempt_of):
        folded.append(details(f"render log, attempt {_attempt_of(path)}", pre(_read(path) or "")))
    prompt = _json(d / layout.PROMPT)
    if isinstance(prompt, dict) and prompt.get("text"):
        folded.append(details(f"prompt ({esc(prompt.get('prompt_version') or '')})",
                              pre(str(prompt["text"]))))
    repair = _read(d / layout.REPAIR_PROMPT)
    if repair is not None:
        folded.append(details("repair prompt", pre(repair)))
    metric_details = _read(d / layout.METRIC_DETAILS)
    if metric_details is not None:
        folded.append(details("metric details", pre(metric_details)))
    return "<h3>Program, replies, logs</h3>" + "".join(folded) if folded else ""


def _key_frames(view: SceneView) -> list[int]:
    prompt = _json(view.scene_dir / layout.PROMPT) or {}
    found = (re.fullmatch(r"frame_(\d+)", str(name)) for name in prompt.get("images") or [])
    return [int(m.group(1)) for m in found if m]


def plots(view: SceneView, media: MediaStore, frames: FrameData) -> str:
    """The per-frame curve and the track overlay (`visphy_core.report.scene_plots`)."""
    r = view.result
    key_frames = _key_frames(view)
    first = f"media/{safe_name(view.scene_id)}/key_frame_{min(key_frames or [1]):02d}.png"
    return scene_plots(safe_name(view.scene_id), view.truth.video, view.truth.missing,
                       view.scene_dir / layout.VIDEO, view.truth.spec,
                       view.scene_dir / layout.METRIC_DETAILS, frames, key_frames,
                       first if first in media.used else None,
                       bool(r is not None and r.fallback))


def scene_section(view: SceneView, media: MediaStore, frames: FrameData | None = None) -> str:
    """The ``<section>`` of one scene (with its plots when ``frames`` is given)."""
    r = view.result
    difficulty = (r.difficulty if r is not None else None) or ""
    head = (f'<h2><a href="#{anchor(view.scene_id)}">{esc(view.scene_id)}</a>'
            f"{badges(view)}</h2>")
    truth_note = (f'<p class="note warn">{esc(view.truth.missing)}</p>'
                  if view.truth.missing else "")
    body = [head, _outcome_text(r), truth_note]
    if view.scene_dir.is_dir() or view.truth.video is not None:
        body += [clips(view, media), keyframes(view, media)]
    if view.scene_dir.is_dir() and frames is not None:
        body.append(plots(view, media, frames))
    if view.scene_dir.is_dir():
        body += [analysis(view), scores(view), verdicts(view), spec_section(view), files(view)]
    return (f'<section class="scene" id={attr(anchor(view.scene_id))} '
            f'data-outcome={attr(outcome_of(r))} data-difficulty={attr(difficulty)}>'
            + "".join(body) + "</section>")
