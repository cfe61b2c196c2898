"""`write_run_report`: one run directory to one folder that opens from disk."""

from __future__ import annotations

from pathlib import Path

from visphy_core.infra.files import atomic_write
from visphy_core.report.frame_data import FrameData
from visphy_core.report.locate_truth import locate_ground_truth
from visphy_core.report.markup import esc, page
from visphy_core.report.media import MediaStore
from visphy_core.report.run_page import counts, header, leaderboard, scene_list
from visphy_core.report.scene_section import SceneView, scene_section
from visphy_core.results.load import RunData, load_run
from visphy_core.results.run_dir import RunDir

#: Up to this many scenes every clip is loaded with the page; longer reports load a clip when
#: it is played or scrubbed (hundreds of clips loading at once stall the page).
EAGER_SCENES = 30


def _scene_ids(run: RunData) -> list[str]:
    """Scenes with a row, then selected scenes without one, then scene folders neither names
    (the scene in progress when a run without a manifest stopped)."""
    ids = [r.scene_id for r in run.results] + run.pending
    scenes_dir = RunDir(run.run_dir).scenes
    if scenes_dir.is_dir():
        ids += sorted(p.name for p in scenes_dir.iterdir() if p.is_dir() and p.name not in ids)
    return ids


def build_run_page(run: RunData, out_dir: Path) -> str:
    """The HTML of ``run``'s report; its media are placed under ``out_dir``."""
    ids = _scene_ids(run)
    truths = locate_ground_truth(run, ids)
    results = {r.scene_id: r for r in run.results}
    media = MediaStore(out_dir)
    preload = "metadata" if len(ids) > EAGER_SCENES else "auto"
    run_files = RunDir(run.run_dir)
    views = [SceneView(scene_id=sid, result=results.get(sid),
                       scene_dir=run_files.scene_dir(sid), truth=truths[sid],
                       summary=run.summary, preload=preload) for sid in ids]
    frames = FrameData(out_dir)
    sections = "".join(scene_section(v, media, frames) for v in views)
    media.close()
    frames.close()
    body = (header(run) + leaderboard(run) + counts(run) + scene_list(run, views)
            + sections + f'<p class="note">written by visphy from {esc(run.run_dir)}</p>')
    return page(f"visphy run {run.name}", body)


def write_run_report(run_dir: Path, out_dir: Path | None = None) -> Path:
    """Write the HTML report of ``run_dir`` (finished or not) into ``out_dir`` (default
    ``<run_dir>/report``); returns the path of its ``index.html``. Clips and key frames are
    copied in (transcoded only where Chromium cannot show them), so the folder works on its own
    from ``file://``. Running it again rewrites the page and copies only what changed."""
    run = load_run(Path(run_dir))
    out = Path(out_dir) if out_dir is not None else run.run_dir / "report"
    out.mkdir(parents=True, exist_ok=True)
    html = build_run_page(run, out)
    return atomic_write(out / "index.html", html)
