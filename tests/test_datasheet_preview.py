"""Datasheet numbers from synthetic entries; contact sheet and animated preview geometry."""

from __future__ import annotations

import json

import numpy as np
import pytest

from visphy_core.infra.video import decode_video
from visphy_plugins.datasets.visphybench.datasheet import LINE_RULE, write_datasheet
from visphy_plugins.datasets.visphybench.preview import (
    GAP,
    LABEL_H,
    cell_origin,
    grid_layout,
    resample_indices,
    write_contact_sheet,
    write_preview,
)


def _entry(sid, template, dim, family, splits, difficulty, objects):
    return {"scene_id": sid, "template_id": template, "dim": dim, "family": family,
            "splits": splits, "difficulty": difficulty, "categories": sorted(objects),
            "n_objects_by_category": objects}


ENTRIES = [
    _entry("task10063_000", "10063", "2d", "combinatorial", ["sub", "test"], "easy",
           {"circle": 2, "line": 3}),
    _entry("task10063_001", "10063", "2d", "combinatorial", ["sub"], "medium",
           {"circle": 1, "rectangle": 2}),
    _entry("task10009_013", "10009", "2d", "law_probe", ["sub", "test"], "hard",
           {"circle": 1, "line": 1, "u_shape": 1}),
    _entry("14_tmpl_14", "tmpl_14", "3d", "ramp", ["sub"], "easy",
           {"circle": 3, "triangle": 1}),
]
REJECTED = {"overlap_at_start": 5, "no_motion": 2, "off_screen": 1}


@pytest.fixture
def sheet(tmp_path):
    md = write_datasheet(tmp_path, ENTRIES, REJECTED, build_seconds=12.34)
    return md, json.loads((tmp_path / "datasheet.json").read_text())


def test_datasheet_counts_and_shares(sheet, tmp_path):
    md, data = sheet
    assert md == tmp_path / "DATASHEET.md" and md.is_file()
    assert data["scenes"] == {"total": 4, "2d": 3, "3d": 1, "paper": 209}
    assert data["templates"] == {"total": 3, "2d": 2, "3d": 1, "paper": 108}
    cats = data["categories"]
    assert list(cats)[:6] == ["circle", "line", "rectangle", "u_shape", "triangle",
                              "composite_shape"]
    assert cats["circle"] | {} == {"scenes": 4, "share_pct": 100.0, "objects": 7,
                                   "paper_share_pct": 100.0, "paper_objects": 779}
    assert (cats["line"]["scenes"], cats["line"]["share_pct"], cats["line"]["objects"]) == \
        (2, 50.0, 4)
    assert (cats["rectangle"]["share_pct"], cats["rectangle"]["paper_share_pct"]) == (25.0, 62.8)
    assert (cats["composite_shape"]["scenes"], cats["composite_shape"]["objects"]) == (0, 0)
    assert data["difficulty"]["sub"] == {
        "counts": {"easy": 2, "medium": 1, "hard": 1, "total": 4},
        "paper": {"easy": 114, "medium": 67, "hard": 28}}
    assert data["difficulty"]["test"]["counts"] == {"easy": 1, "medium": 0, "hard": 1, "total": 2}
    assert data["families"]["combinatorial"] == {"scenes": 2, "templates": 1, "dims": ["2d"]}
    assert list(data["families"]) == ["combinatorial", "law_probe", "ramp"]
    assert data["rejected"] == {"by_reason": {"no_motion": 2, "off_screen": 1,
                                              "overlap_at_start": 5}, "total": 8}
    assert data["line_rectangle_rule"] == LINE_RULE
    assert data["build_seconds"] == 12.3


def test_datasheet_markdown_shows_numbers_next_to_the_paper(sheet):
    text = sheet[0].read_text()
    assert "| circle | 4 | 100.0% | 7 | 100.0% | 779 |" in text
    assert "| line | 2 | 50.0% | 4 | 83.2% | 344 |" in text
    assert "| composite_shape | 0 | 0.0% | 0 | 7.3% | 16 |" in text
    assert "| sub | 2 | 1 | 1 | 0 | 4 | 114/67/28 |" in text
    assert "| test | 1 | 0 | 1 | 0 | 2 | 29/17/3 |" in text
    assert "| scenes | 4 | 3 | 1 | 209 |" in text and "| templates | 3 | 2 | 1 | 108 |" in text
    assert "| overlap_at_start | 5 |" in text and "| **total** | 8 |" in text
    assert "length/thickness ≥ 4" in text
    assert "Build time: 12.3 s" in text


def test_datasheet_is_deterministic_without_build_time(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    write_datasheet(a, ENTRIES, REJECTED, None)
    write_datasheet(b, list(reversed(ENTRIES)), dict(reversed(list(REJECTED.items()))), None)
    for name in ("DATASHEET.md", "datasheet.json"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert "Build time" not in (a / "DATASHEET.md").read_text()
    assert json.loads((a / "datasheet.json").read_text())["build_seconds"] is None
    assert not [p for p in a.iterdir() if p.name.startswith(".")]  # no temp files left


def test_datasheet_extra_category_and_unlabelled_difficulty(tmp_path):
    entries = ENTRIES + [_entry("15_tmpl_15", "tmpl_15", "3d", "ramp", ["dev"], None,
                                {"circle": 1, "plank": 2})]
    write_datasheet(tmp_path, entries, {}, None)
    data = json.loads((tmp_path / "datasheet.json").read_text())
    assert data["categories"]["plank"] == {"scenes": 1, "share_pct": 20.0, "objects": 2,
                                           "paper_share_pct": None, "paper_objects": None}
    assert list(data["difficulty"]) == ["sub", "test", "dev"]
    assert data["difficulty"]["dev"] == {"counts": {"easy": 0, "medium": 0, "hard": 0,
                                                    "unlabelled": 1, "total": 1}, "paper": None}
    assert "No candidate was rejected." in (tmp_path / "DATASHEET.md").read_text()


def test_datasheet_rejects_incomplete_entries(tmp_path):
    bad = dict(ENTRIES[0])
    del bad["family"]
    with pytest.raises(ValueError, match="task10063_000: missing key.*family"):
        write_datasheet(tmp_path, [bad], {}, None)


# --------------------------------------------------------------------------- previews

COLOURS = [(200, 30, 30), (30, 200, 30), (30, 30, 200), (200, 200, 30), (30, 200, 200)]


def _solid(colour, size=64, n=None):
    shape = (size, size, 3) if n is None else (n, size, size, 3)
    return np.broadcast_to(np.array(colour, dtype=np.uint8), shape).copy()


def test_contact_sheet_grid_and_thumbnail_pixels(tmp_path):
    from PIL import Image

    frames = [(f"task1000{i}_000", _solid(c)) for i, c in enumerate(COLOURS)]
    path = write_contact_sheet(frames, tmp_path / "sheet.png", columns=3, thumb=32)
    img = np.asarray(Image.open(path).convert("RGB"))
    cols, rows, width, height = grid_layout(5, 3, 32)
    assert (cols, rows) == (3, 2)
    assert img.shape == (height, width, 3) == (2 * (32 + LABEL_H) + 3 * GAP, 3 * 32 + 4 * GAP, 3)
    for i, colour in enumerate(COLOURS):
        x, y = cell_origin(i, cols, 32)
        cell = img[y : y + 32, x : x + 32].reshape(-1, 3)
        assert (cell == colour).all(), i
        label = img[y + 32 : y + 32 + LABEL_H, x : x + 32]
        assert (label < 128).any() and (label == 255).any()  # dark text on a white strip
    x, y = cell_origin(5, cols, 32)  # the empty sixth cell stays background
    assert (img[y : y + 32, x : x + 32] == 224).all()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_contact_sheet_keeps_aspect_ratio_with_white_padding(tmp_path):
    from PIL import Image

    wide = np.zeros((32, 64, 3), dtype=np.uint8)
    path = write_contact_sheet([("14_tmpl_14", wide)], tmp_path / "s.png", thumb=32)
    img = np.asarray(Image.open(path).convert("RGB"))
    x, y = cell_origin(0, 1, 32)
    thumb = img[y : y + 32, x : x + 32]
    assert (thumb[:8] == 255).all() and (thumb[8:24] == 0).all() and (thumb[24:] == 255).all()


def test_resample_indices_nearest_in_time():
    assert resample_indices(17, 17).tolist() == list(range(17))
    idx = resample_indices(75, 17)
    assert idx[0] == 0 and idx[-1] == 74 and len(idx) == 17
    assert idx[8] == 37  # the middle frame of each clip shows the middle of the motion
    assert resample_indices(3, 5).tolist() == [0, 1, 1, 2, 2]
    assert resample_indices(9, 1).tolist() == [0]


def test_preview_mixes_2d_and_3d_clips(tmp_path):
    # 2D: 17 frames whose colour encodes the frame index; 3D: 75 frames likewise.
    clip2d = np.stack([_solid((k * 15, 0, 0)) for k in range(17)])
    clip3d = np.stack([_solid((0, k * 3, 0)) for k in range(75)])
    clips = [("task10063_000", clip2d), ("14_tmpl_14", clip3d), ("task10009_013", clip2d)]
    path = write_preview(clips, tmp_path / "preview.mp4", fps=5, thumb=30)
    frames, info = decode_video(path)
    cols, rows, width, height = grid_layout(3, 2, 30)  # ceil(sqrt(3)) = 2 columns
    assert (cols, rows) == (2, 2)
    assert info.n_frames == 17 and info.fps == 5
    assert (info.width, info.height) == (width + width % 2, height + height % 2)
    assert info.width % 2 == 0 and info.height % 2 == 0
    # The 3D clip is resampled in time: its last preview frame is its last frame.
    x, y = cell_origin(1, cols, 30)
    green_last = frames[-1, y + 5 : y + 25, x + 5 : x + 25, 1].mean()
    green_mid = frames[8, y + 5 : y + 25, x + 5 : x + 25, 1].mean()
    assert abs(green_last - 74 * 3) < 8 and abs(green_mid - 37 * 3) < 8
    x, y = cell_origin(0, cols, 30)
    assert abs(frames[8, y + 5 : y + 25, x + 5 : x + 25, 0].mean() - 8 * 15) < 8


def test_preview_limits_scenes_and_frames(tmp_path):
    clips = [(f"task1000{i}_000", _solid(c, n=17)) for i, c in enumerate(COLOURS)]
    path = write_preview(clips, tmp_path / "p.mp4", thumb=16, max_scenes=4, n_frames=6)
    frames, info = decode_video(path)
    _, _, width, height = grid_layout(4, 2, 16)
    assert frames.shape == (6, height + height % 2, width + width % 2, 3)
    with pytest.raises(ValueError, match="no clip"):
        write_preview([], tmp_path / "none.mp4")
