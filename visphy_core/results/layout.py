"""The run directory's layout: what each file is called and what makes a folder a run.

A run directory (``<runs_dir>/<date>_<model>_<engine>_<hash>``, `visphy_core.results.run_dir`)
holds:

* ``config.yaml``: the run's resolved config, credentials removed;
* ``manifest.json``: the command, the config hash, the scenes selected, the status
  (``running``, ``interrupted``, ``failed``, ``cost_cap``, ``finished``), the metrics;
* ``results.jsonl``: one row per scene (`visphy_core.results.row.SceneResult`), appended and
  fsynced as each scene finishes — what a resumed run and a report of a killed run read;
* ``results.parquet``: the same rows, written when the run closes;
* ``summary.json``: counts and means (`visphy_core.results.summary`), written when it closes;
* ``calls.jsonl``: every model and judge call with its usage and cost;
* ``scenes/<scene_id>/``: the scene's replies, program, clips and per-scene scores (their
  names below: `VIDEO`, `SCORES`…, and per attempt `attempt_file`);
* ``human_ratings.jsonl``: ratings added later by the rating page (`visphy_core.human`);
* ``.lock``: held by the process working in the folder.

A study (a multirun, `visphy_core.results.study_records`) adds ``study.json`` to its sweep
folder, ``visphy_job.json`` to each job's folder and, when it ends, ``study_summary.json`` (the
jobs, their outcomes and where every output is) to the sweep folder.

Every file is written through `visphy_core.infra.files` (atomic, never through a link), and
read and written through `visphy_core.results.run_dir.RunDir`: no module outside
`visphy_core.results` spells one of these names (tests/test_layering.py).
"""

from __future__ import annotations

from pathlib import Path

CONFIG = "config.yaml"
MANIFEST = "manifest.json"
SUMMARY = "summary.json"
RESULTS_JSONL = "results.jsonl"
RESULTS_PARQUET = "results.parquet"
CALLS = "calls.jsonl"
SCENES = "scenes"
RATINGS = "human_ratings.jsonl"
LOCK = ".lock"
STUDY_FILE = "study.json"
JOB_FILE = "visphy_job.json"
STUDY_SUMMARY = "study_summary.json"

#: A run's own files at its top level (its scenes aside), in the order tracking logs them.
RUN_FILES = (CONFIG, MANIFEST, SUMMARY, RESULTS_PARQUET, RESULTS_JSONL, CALLS)
#: What a finished run has: the files merging a shard reads.
FINISHED_FILES = (CONFIG, MANIFEST, SUMMARY, RESULTS_JSONL)
#: What re-scoring reads (a run killed before its summary can be re-scored).
SCORABLE_FILES = (CONFIG, MANIFEST, RESULTS_JSONL)
#: What a run's config and rows make: the files re-scoring writes anew.
DERIVED_FILES = (CONFIG, MANIFEST, SUMMARY, RESULTS_JSONL, RESULTS_PARQUET)
#: Every file name the format owns.
FILE_NAMES = (*RUN_FILES, RATINGS, STUDY_FILE, JOB_FILE, STUDY_SUMMARY)

# ----------------------------------------------------- a scene's folder: ``scenes/<scene_id>/``
#: The clip scored: the program's render, the model's own video, or the fallback clip.
VIDEO = "video.mp4"
SPEC_VIDEO = "spec_video.mp4"          # the spec track: S simulated and replayed
TWIN_VIDEO = "twin_video.mp4"          # the ground truth's twin (variance normalisation)
PROMPT = "prompt.json"                 # the first request, as sent
REPAIR_PROMPT = "repair_prompt.txt"
ANALYSIS = "analysis.txt"              # the reply's analysis A
FRAMES_META = "frames_meta.json"       # what the render reported about its frames
REFERENCE = "reference.txt"            # the reference description the text metrics read
SCORES = "scores.json"                 # the row's scores and why any is missing
METRIC_DETAILS = "metric_details.json"
VERDICTS = "verdicts.json"
NORMALISATION = "normalisation.json"
HEADLINE = "headline.json"
#: What scoring writes into a scene's folder: removed before a row is scored again.
SCORE_FILES = (SCORES, METRIC_DETAILS, VERDICTS, NORMALISATION, REFERENCE, HEADLINE)
#: Every fixed name in a scene's folder.
SCENE_FILES = (VIDEO, SPEC_VIDEO, TWIN_VIDEO, PROMPT, REPAIR_PROMPT, ANALYSIS, FRAMES_META,
               *SCORE_FILES)
#: Per attempt (`attempt_file`): the reply's text (``.txt``) and its metadata (``.json``), a
#: video model's own clip (``.mp4``), the program (``.html`` / ``.py``), the scene spec S and
#: its validation, the render log and a partial clip.
RESPONSE, REPLY, PROGRAM, SPEC, SPEC_VALIDATION, RENDER_LOG, PARTIAL = (
    "response", "reply", "program", "spec", "spec_validation", "render", "partial")
#: ``visphy render``'s folder holds a scene folder's files and the row, here.
RESULT = "result.json"


def attempt_suffix(attempt: int) -> str:
    """What tells an attempt's files apart: nothing for the first, ``.attempt2`` for the
    repair."""
    return "" if attempt <= 1 else f".attempt{attempt}"


def attempt_file(stem: str, attempt: int, ext: str) -> str:
    """``response.txt`` (attempt 1), ``program.attempt2.html``…: one attempt's file."""
    return f"{stem}{attempt_suffix(attempt)}.{ext}"


#: Files only a run writes: a folder holding any of them is a run directory, finished or not
#: (a killed run may have no summary). ``config.yaml`` alone is not one (Hydra writes one in
#: every job's ``.hydra/``): it counts beside a ``scenes/`` folder.
RUN_MARKERS = (MANIFEST, RESULTS_JSONL, SUMMARY)


def is_run_dir(path: str | Path) -> bool:
    """``path`` is a run directory: a folder with any of `RUN_MARKERS`, or with ``config.yaml``
    and ``scenes/``."""
    path = Path(path)
    if not path.is_dir():
        return False
    if any((path / marker).is_file() for marker in RUN_MARKERS):
        return True
    return (path / CONFIG).is_file() and (path / SCENES).is_dir()


#: The one status of a complete run: every selected scene has its row, and the run's files
#: are all written. Every other status (``running``: still going or killed, ``interrupted``,
#: ``failed``, ``cost_cap``) is a run that rerunning its command resumes.
COMPLETE = "finished"


def run_status(path: str | Path) -> str:
    """A run directory's status: its manifest's, else its summary's, else ``unknown``."""
    import json

    for name in (MANIFEST, SUMMARY):
        try:
            data = json.loads((Path(path) / name).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and data.get("status"):
            return str(data["status"])
    return "unknown"


def is_finished_run(path: str | Path) -> bool:
    """A complete run directory: it has its ``summary.json`` and its status is `COMPLETE`."""
    return (is_run_dir(path) and (Path(path) / SUMMARY).is_file()
            and run_status(path) == COMPLETE)
