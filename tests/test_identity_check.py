"""The before/after identity check (`benchmarks/identity_check.py`) tells a changed score,
frame or file from what legitimately differs between two runs (times, paths, call order)."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from identity_check import compare  # noqa: E402


def run_dir(root: Path, name: str) -> Path:
    d = root / "home" / "runs" / name
    (d / "scenes" / "s1").mkdir(parents=True)
    (d / "results.jsonl").write_text(json.dumps(
        {"scene_id": "s1", "score_psnr": 31.5, "render_wall_s": 0.4}) + "\n")
    (d / "manifest.json").write_text(json.dumps(
        {"started": "10:00", "run_dir": str(d), "scenes": ["s1"]}))
    (d / "calls.jsonl").write_text('{"scene_id": "a", "latency_s": 1}\n'
                                   '{"scene_id": "b", "latency_s": 2}\n')
    (d / "scenes" / "s1" / "video.mp4").write_bytes(b"\x00\x01frames")
    return d


def test_identical_runs_and_what_may_differ(tmp_path):
    a = run_dir(tmp_path / "x", "run-a")
    b = run_dir(tmp_path / "y", "run-b")
    homes = (str(tmp_path / "x" / "home"), str(tmp_path / "y" / "home"))
    (b / "results.jsonl").write_text(json.dumps(
        {"scene_id": "s1", "score_psnr": 31.5, "render_wall_s": 9.9}) + "\n")   # a time
    (b / "calls.jsonl").write_text('{"scene_id": "b", "latency_s": 5}\n'
                                   '{"scene_id": "a", "latency_s": 3}\n')     # call order
    assert compare(a, b, homes) == []


def test_a_changed_score_frame_or_file_is_reported(tmp_path):
    a = run_dir(tmp_path / "x", "run-a")
    homes = (str(tmp_path / "x" / "home"), str(tmp_path / "y" / "home"))
    b = tmp_path / "y" / "home" / "runs" / "run-b"
    shutil.copytree(a, b)
    (b / "results.jsonl").write_text(json.dumps(
        {"scene_id": "s1", "score_psnr": 31.500001, "render_wall_s": 0.4}) + "\n")
    (b / "scenes" / "s1" / "video.mp4").write_bytes(b"\x00\x02frames")
    (b / "scenes" / "s1" / "extra.json").write_text("{}")
    diffs = compare(a, b, homes)
    assert diffs == ["only in the second run: scenes/s1/extra.json",
                     "results.jsonl: differs (volatile keys excluded)",
                     "scenes/s1/video.mp4: bytes differ"]
