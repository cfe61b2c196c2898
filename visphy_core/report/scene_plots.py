"""A scene's plots in the run report: the per-frame PSNR curve against the ground truth (the
still clip's beside it for scale) and the tracked bodies' paths in both clips drawn over the
first key frame. The data come from `visphy_core.report.frame_data` (computed once per pair of
clips, cached beside the report's media); a plot that cannot be drawn is one line saying why.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from visphy_core.api.psnr import PSNR_CAP_DB
from visphy_core.report.frame_data import MAX_FRAMES, FrameData
from visphy_core.report.markup import attr, esc, fmt, url
from visphy_core.report.plots import PSNR_CAP, _why
from visphy_core.report.svg import (MUTED, SERIES, hex_colour, line, n, nice_ticks,
                                    points, runs_of, svg, text)


def psnr_curve(data: dict, key_frames: list[int], fallback: bool) -> str:
    """Per-frame PSNR (dB) of the generated clip and of the still clip against the ground
    truth, frames by index."""
    if data.get("psnr_error"):
        return _why(data["psnr_error"], "psnr-curve")
    gen, still = data.get("psnr") or [], data.get("still") or []
    if not gen:
        return _why("no per-frame curve: the clips have no frame in common", "psnr-curve")
    hi = min(PSNR_CAP, max(gen + still))
    lo = min(gen + still)
    if lo >= PSNR_CAP:  # every frame a (near-)perfect match: the chart's top band
        lo = hi - 10.0
    step = 10.0 if hi - lo > 25 else 5.0 if hi - lo > 8 else 1.0
    lo, hi = math.floor(lo / step) * step, max(math.ceil(hi / step) * step, lo + step)
    left, top, width, height = 44.0, 24.0, 380.0, 150.0
    count = len(gen)

    def x(i: int) -> float:
        return left + (i / max(count - 1, 1)) * width

    def y(v: float) -> float:
        v = min(max(v, lo), hi)
        return top + (hi - v) / (hi - lo) * height

    body = []
    for t in nice_ticks(lo, hi, 6):
        body.append(line(left, y(t), left + width, y(t)))
        body.append(text(left - 4, y(t) + 4, fmt(t, 3), "end", fill=MUTED))
    for f in sorted(set(key_frames)):
        if 1 <= f <= count:
            body.append(line(x(f - 1), top, x(f - 1), top + height, MUTED, 1,
                             ' stroke-dasharray="2 3"'))
            body.append(text(x(f - 1), top - 6, f"key frame {f}", "middle", fill=MUTED,
                             size=9))
    for t in nice_ticks(1, count, 6):
        if float(t).is_integer() and 1 <= t <= count:
            body.append(text(x(int(t) - 1), top + height + 14, int(t), "middle", fill=MUTED))
    body.append(text(left + width / 2, top + height + 28, "frame (ground truth and generated "
                     "paired by index)", "middle", fill=MUTED, size=10))
    for name, series, colour, dash in (("still clip (first frame held)", still, MUTED, "5 4"),
                                       ("generated" + (" (fallback clip)" if fallback else ""),
                                        gen, SERIES[0], "")):
        pts = [(x(i), y(v)) for i, v in enumerate(series)]
        marks = "".join(f'<circle cx="{n(px)}" cy="{n(py)}" r="{2.5 if not dash else 1.5}" '
                        f'fill="{colour}"/>' for px, py in pts)
        values = ",".join(repr(v) for v in series)
        body.append(f'<g class="series" data-series={attr(name)} data-values={attr(values)}>'
                    f'<polyline points="{points(pts)}" fill="none" stroke="{colour}" '
                    f'stroke-width="{1.5 if dash else 2}"'
                    + (f' stroke-dasharray="{dash}"' if dash else "") + f"/>{marks}</g>")
    legend_y = top + height + 44
    body.append(line(left, legend_y - 4, left + 24, legend_y - 4, SERIES[0], 2))
    body.append(text(left + 30, legend_y, "generated" + (" (fallback)" if fallback else "")))
    body.append(line(left + 150, legend_y - 4, left + 174, legend_y - 4, MUTED, 1.5,
                     ' stroke-dasharray="5 4"'))
    body.append(text(left + 180, legend_y, "still clip (first frame held)"))
    note = ""
    if PSNR_CAP_DB in gen:
        note += (f" · identical frames ({fmt(PSNR_CAP_DB, 3)} dB, the psnr metric's cap) drawn "
                 f"at the top, {fmt(hi, 3)} dB")
    if data.get("n_truth") != data.get("n_generated"):
        note += (f" · ground truth {data.get('n_truth')} frames, generated "
                 f"{data.get('n_generated')}: {count} compared")
    if data.get("cut"):
        note += f" · the first {MAX_FRAMES} frames only"
    caption = "PSNR per frame against the ground truth (dB, ↑ higher is better)"
    return (f'<figure class="plot psnr-curve" data-frames="{count}"><figcaption>'
            f'{esc(caption)}</figcaption>'
            + svg(left + width + 12, legend_y + 8, "".join(body), caption)
            + (f'<p class="note">{esc(note.lstrip(" ·"))}</p>' if note else "") + "</figure>")


def track_overlay(data: dict, background: str | None) -> str:
    """Each tracked body's path in the ground truth (solid) and in the generated clip (dashed),
    over the first key frame (or a blank canvas of the frame's size)."""
    tracks = data.get("tracks")
    if isinstance(tracks, str):
        return _why(f"no track overlay: {tracks}", "track-overlay")
    if not isinstance(tracks, dict) or not data.get("size"):
        return _why("no track overlay: no tracks", "track-overlay")
    w, h = data["size"]
    body = [f'<rect width="{w}" height="{h}" fill="#fff"/>']
    if background:
        body.append(f'<image href={attr(url(background))} width="{w}" height="{h}" '
                    'opacity="0.45"/>')
    scale = max(w, h) / 320.0  # strokes keep their width on the 320 px wide figure
    legend = []
    for ident, colour, truth, gen in zip(tracks["ids"], tracks["colours"], tracks["truth"],
                                         tracks["generated"]):
        col = hex_colour(colour)
        for clip, path, dash in (("ground truth", truth, ""), ("generated", gen, "5 3")):
            found = sum(p is not None for p in path)
            if dash:
                style = (f'stroke="{col}" stroke-width="{n(2.5 * scale)}" stroke-dasharray="'
                         f'{n(5 * scale)} {n(3 * scale)}"')
                halo = f'stroke="#1d2330" stroke-width="{n(4 * scale)}" stroke-opacity="0.55"'
            else:
                style = f'stroke="{col}" stroke-width="{n(7 * scale)}" stroke-opacity="0.5"'
                halo = f'stroke="#fff" stroke-width="{n(9 * scale)}" stroke-opacity="0.6"'
            parts = []
            for run in runs_of(path):
                pts = points((path[i][0], path[i][1]) for i in run)
                parts.append(f'<polyline points="{pts}" fill="none" {halo} '
                             'stroke-linejoin="round" stroke-linecap="round"/>'
                             f'<polyline class="path" points="{pts}" fill="none" {style} '
                             'stroke-linejoin="round" stroke-linecap="round"/>')
            if found:
                first = next(p for p in path if p is not None)
                shape = (f'<circle cx="{n(first[0])}" cy="{n(first[1])}" r="{n(5 * scale)}" '
                         if not dash else
                         f'<rect x="{n(first[0] - 3 * scale)}" y="{n(first[1] - 3 * scale)}"'
                         f' width="{n(6 * scale)}" height="{n(6 * scale)}" ')
                parts.append(shape + f'fill="{col}" stroke="#1d2330" '
                             f'stroke-width="{n(scale)}"/>')
            body.append(f'<g class="track" data-body={attr(ident)} data-clip={attr(clip)} '
                        f'data-found="{found}" data-frames="{len(path)}">'
                        + "".join(parts) + "</g>")
        n_t, n_g = (sum(p is not None for p in s) for s in (truth, gen))
        lost = f", generated {n_g}/{len(gen)}" + (" (drawn in another colour, or absent)"
                                                   if n_g < len(gen) / 2 else "")
        legend.append(f'<li><span class="swatch" style="background:{col}"></span>'
                      f'{esc(ident)} <span class="note">found in ground truth '
                      f"{n_t}/{len(truth)}{esc(lost)}</span></li>")
    caption = ("tracked bodies' paths: ground truth a wide pale band (● start), generated "
               "dashed (■ start)"
               + ("" if background else ", on a blank canvas of the frame's size"))
    return (f'<figure class="plot track-overlay" data-bodies="{len(tracks["ids"])}">'
            f'<figcaption>{esc(caption)}</figcaption>'
            + svg(w, h, "".join(body), caption, extra=' preserveAspectRatio="xMidYMid meet"')
            + f'<ul class="track-legend">{"".join(legend)}</ul><p class="note">centroids of '
            "each body's colour (a quick colour look-up for this picture; the track metrics "
            "use a stricter tracker)</p></figure>")


def scene_plots(scene_key: str, truth: Path | None, truth_missing: str | None,
                generated: Path, spec: Path | None, details: Path, frames: FrameData,
                key_frames: list[int], background: str | None, fallback: bool) -> str:
    """The scene's per-frame curve and track overlay, or one line each saying why not."""
    if truth is None:
        why = f"no plots: {truth_missing or 'no ground-truth clip'}"
        return f'<h3>Per frame</h3>{_why(why, "psnr-curve")}'
    if not generated.is_file():
        why = "no plots: no generated clip (the program produced none and no fallback was " \
              "rendered)"
        return f'<h3>Per frame</h3>{_why(why, "psnr-curve")}'
    data: dict[str, Any] = frames.get(scene_key, truth, generated, spec, details)
    if data.get("error"):
        return f'<h3>Per frame</h3>{_why("no plots: " + data["error"], "psnr-curve")}'
    return ('<h3>Per frame</h3><div class="plots">'
            + psnr_curve(data, key_frames, fallback) + track_overlay(data, background)
            + "</div>")
