"""What the site copies from each run: its report, and a few clips of its best and worst scenes.

Each run's report (`visphy_core.report.write_run_report`) is written into
``runs/<row>/`` of the site, so the site works on its own, from disk or any static host. Media
are capped so a site of many long runs stays deployable: a clip larger than ``max_clip_mb`` is
left out of the copy, and when a report's media together exceed ``max_report_mb`` its largest
clips are left out until they fit. A left-out clip's element keeps its place in the page (its
``src`` becomes ``data-omitted``) and the page says how many were left out and that the run
directory still holds them. The side-by-side clips (generated beside ground truth) of the
``n`` best and ``n`` worst scenes by headline go to ``clips/<row>/`` under the same per-clip cap.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from visphy_core.leaderboard.entries import Entry
from visphy_core.report.locate_truth import locate_ground_truth
from visphy_core.report.markup import attr, url
from visphy_core.report.media import MediaStore, Placed
from visphy_core.report.run_report import write_run_report
from visphy_core.results.layout import VIDEO
from visphy_core.results.run_dir import RunDir

#: Defaults of the caps (MB): one clip, and one report's media together.
MAX_CLIP_MB = 20.0
MAX_REPORT_MB = 200.0
VIDEO_SUFFIXES = (".mp4", ".webm", ".mkv", ".mov")
OMITTED_NOTE = "leaderboard-omitted"


@dataclass
class SceneClips:
    """One scene's pair of clips in the site (paths relative to the site root)."""

    scene_id: str
    value: float
    generated: Placed
    truth: Placed


def _mb(path: Path) -> float:
    return path.stat().st_size / 1e6


def cap_media(report_dir: Path, max_clip_mb: float, max_report_mb: float) -> list[str]:
    """Leave out the report's clips over the caps (largest first); returns the paths left
    out, relative to ``report_dir``."""
    clips = sorted((p for p in (report_dir / "media").rglob("*")
                    if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES),
                   key=lambda p: p.stat().st_size, reverse=True)
    total = sum(_mb(p) for p in report_dir.rglob("*") if p.is_file())
    dropped = []
    for clip in clips:
        if _mb(clip) <= max_clip_mb and total <= max_report_mb:
            break
        total -= _mb(clip)
        dropped.append(clip.relative_to(report_dir).as_posix())
        clip.unlink()
    if dropped:
        index = report_dir / "index.html"
        html = index.read_text(encoding="utf-8")
        for rel in dropped:
            html = html.replace(f"src={attr(url(rel))}", f"data-omitted={attr(url(rel))}")
        banner = (f'<p class="note {OMITTED_NOTE}">This copy leaves out {len(dropped)} clip(s) '
                  f"over the leaderboard's media caps ({max_clip_mb:g} MB a clip, "
                  f"{max_report_mb:g} MB a report); the run directory holds them.</p>")
        html = html.replace("<body>", "<body>" + banner, 1)
        index.write_text(html, encoding="utf-8")
    return dropped


def copy_report(entry: Entry, site: Path, max_clip_mb: float = MAX_CLIP_MB,
                max_report_mb: float = MAX_REPORT_MB) -> tuple[Path, list[str]]:
    """Write ``entry``'s run report into the site; its ``index.html`` and the clips left out."""
    out = site / "runs" / entry.slug
    index = write_run_report(entry.run.run_dir, out)
    return index, cap_media(out, max_clip_mb, max_report_mb)


def best_and_worst(entry: Entry, site: Path, n: int = 2,
                   max_clip_mb: float = MAX_CLIP_MB) -> tuple[list[SceneClips], list[SceneClips]]:
    """Side-by-side clips of the ``n`` best and ``n`` worst scenes (fewer when the run has
    fewer than 2n scored scenes: a scene is shown once)."""
    ranked = entry.values.sort_values(ascending=False)
    if ranked.empty:
        return [], []
    best_ids = list(ranked.index[:n])
    worst_ids = [s for s in list(ranked.index[::-1][:n]) if s not in best_ids]
    truths = locate_ground_truth(entry.run, best_ids + worst_ids)
    store = MediaStore(site / "clips" / entry.slug)

    def placed(src: Path | None, rel: str) -> Placed:
        if src is not None and src.is_file() and _mb(src) > max_clip_mb:
            return Placed(None, error=f"clip over {max_clip_mb:g} MB left out")
        return store.video(src, rel)

    def clips(ids: list[str]) -> list[SceneClips]:
        out = []
        for sid in ids:
            scene_dir = RunDir(entry.run.run_dir).scene_dir(sid)
            out.append(SceneClips(sid, float(ranked[sid]),
                                  placed(scene_dir / VIDEO, f"media/{sid}/generated.mp4"),
                                  placed(truths[sid].video, f"media/{sid}/truth.mp4")))
        return out

    result = clips(best_ids), clips(worst_ids)
    store.close()
    return result
