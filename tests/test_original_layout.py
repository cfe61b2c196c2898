"""The original VisPhyBench-Data layout: synthetic split trees, format variants, one-line errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from visphy_core.infra.video import encode_video
from visphy_plugins.datasets.original import (
    difficulty_label,
    load_original,
    probe_clip,
    read_difficulty_table,
)

ID_2D_A, ID_2D_B, ID_3D = "task10063_000", "task10009_013", "14_tmpl_14"


def _clip(dim: str, shade: int) -> np.ndarray:
    """A tiny 64×64 clip: 2D = 17 frames (5 fps), 3D = 75 frames (15 fps); a square moves down."""
    n = 17 if dim == "2d" else 75
    frames = np.full((n, 64, 64, 3), 255, dtype=np.uint8)
    for k in range(n):
        y = min(48, 2 + k * 46 // (n - 1))
        frames[k, y : y + 14, 20:34] = (shade, 40, 255 - shade)
    return frames


@pytest.fixture(scope="module")
def clip_files(tmp_path_factory) -> dict[str, Path]:
    """One encoded clip per scene id, written once and copied into every tree."""
    out = tmp_path_factory.mktemp("clips")
    return {
        ID_2D_A: encode_video(_clip("2d", 200), out / f"{ID_2D_A}.mp4", 5),
        ID_2D_B: encode_video(_clip("2d", 90), out / f"{ID_2D_B}.mp4", 5),
        ID_3D: encode_video(_clip("3d", 30), out / f"{ID_3D}.mp4", 15),
    }


def _detection(sid: str) -> dict:
    return {"image_size": {"width": 64, "height": 64},
            "coordinate_system": "pixels, origin top-left",
            "objects": [{"id": "red_ball", "category": "circle", "color_rgb": [243, 79, 70],
                         "note": sid}]}


def make_split(root: Path, split: str, clip_files: dict[str, Path], ids: list[str],
               metadata: list | None | str = "default", difficulty: object = "default") -> Path:
    """Write ``root/split`` in the VisPhyBench-Data layout; returns the split folder."""
    d = root / split
    (d / "videos").mkdir(parents=True, exist_ok=True)
    (d / "detection_json").mkdir(exist_ok=True)
    for sid in ids:
        shutil.copyfile(clip_files[sid], d / "videos" / f"{sid}.mp4")
        (d / "detection_json" / f"{sid}_frame_01.json").write_text(json.dumps(_detection(sid)))
    if metadata == "default":
        metadata = [{"scene_id": sid, "caption": f"scene {sid}"} for sid in ids]
    if metadata is not None:
        (d / "metadata.jsonl").write_text("".join(json.dumps(m) + "\n" for m in metadata))
    if difficulty == "default":
        difficulty = {sid: label for sid, label in zip(ids, ("easy", "medium", "hard"))}
    if difficulty is not None:
        (d / "difficulty_table.json").write_text(json.dumps(difficulty))
    return d


def _one_line_error(excinfo, *needles: str) -> str:
    text = str(excinfo.value)
    assert "\n" not in text, text
    for needle in needles:
        assert needle in text, (needle, text)
    return text


# --------------------------------------------------------------------------- loading


def test_scenes_load_with_dim_clip_difficulty_and_detection(tmp_path, clip_files):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D, ID_2D_B])
    scenes = load_original(tmp_path, "sub")
    assert [s.scene_id for s in scenes] == [ID_2D_A, ID_3D, ID_2D_B]  # metadata order
    a, b, c = scenes
    assert (a.dim, b.dim, c.dim) == ("2d", "3d", "2d")
    assert (a.clip.fps, a.clip.n_frames, a.clip.width, a.clip.height) == (5.0, 17, 64, 64)
    assert (b.clip.fps, b.clip.n_frames, b.clip.width, b.clip.height) == (15.0, 75, 64, 64)
    assert [s.difficulty for s in scenes] == ["easy", "medium", "hard"]
    assert a.detection["objects"][0]["note"] == ID_2D_A
    assert b.detection_path == tmp_path / "sub" / "detection_json" / f"{ID_3D}_frame_01.json"
    assert a.video_path == tmp_path / "sub" / "videos" / f"{ID_2D_A}.mp4"
    assert a.dataset == "visphybench/sub"
    assert a.spec_path is None and a.trajectory_path is None and a.keyframe_paths == {}
    assert a.spec is None and a.trajectory is None
    assert (a.template_id, b.template_id) == ("10063", "tmpl_14")
    # Key frames come from decoding the clip; the header's frame count matches the decode.
    assert a.key_frame(10).shape == (64, 64, 3)
    assert len(b.reference_frames()) == b.clip.n_frames


def test_probe_counts_packets_when_the_header_has_no_frame_count(tmp_path):
    import av

    path = tmp_path / "clip.mkv"
    frame = np.zeros((64, 64, 3), dtype=np.uint8)
    with av.open(str(path), "w", format="matroska") as container:
        stream = container.add_stream("libx264", rate=5)
        stream.width, stream.height, stream.pix_fmt = 64, 64, "yuv420p"
        for _ in range(17):
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    with av.open(str(path)) as container:
        assert container.streams.video[0].frames == 0  # the case being tested
    info = probe_clip(path)
    assert (info.fps, info.n_frames, info.width, info.height) == (5.0, 17, 64, 64)


@pytest.mark.parametrize("key, value, expect", [
    ("scene_id", ID_3D, ID_3D),
    ("id", ID_3D, ID_3D),
    ("video_id", ID_2D_A, ID_2D_A),
    ("video", "task10063_000.mp4", ID_2D_A),
    ("video", "videos/14_tmpl_14.mp4", ID_3D),
])
def test_metadata_may_name_the_scene_several_ways(tmp_path, clip_files, key, value, expect):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D],
               metadata=[{key: value, "other": 1}])
    assert [s.scene_id for s in load_original(tmp_path, "sub")] == [expect]


def test_metadata_template_and_difficulty_fields_are_used(tmp_path, clip_files):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D], difficulty=None, metadata=[
        {"id": ID_2D_A, "template_id": 7, "difficulty": 4},
        {"id": ID_3D}])
    a, b = load_original(tmp_path, "sub")
    assert (a.template_id, a.difficulty) == ("7", "hard")
    assert (b.template_id, b.difficulty) == ("tmpl_14", None)


def test_without_metadata_the_sorted_videos_listing_is_used(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D, ID_2D_B], metadata=None)
    (d / "videos" / "notes.txt").write_text("not a video")
    assert [s.scene_id for s in load_original(tmp_path, "sub")] == sorted(
        [ID_2D_A, ID_3D, ID_2D_B])


@pytest.mark.parametrize("table, expect", [
    ({ID_2D_A: "Easy", ID_3D: " HARD "}, ["easy", "hard"]),
    ({ID_2D_A: {"difficulty": 2, "votes": 5}, ID_3D: {"label": "medium"}}, ["easy", "medium"]),
    ({f"{ID_2D_A}.mp4": {"rating": 1}, ID_3D: {"ratings": [4, 5, 4]}}, ["easy", "hard"]),
    ([{"scene_id": ID_2D_A, "difficulty": "3"}, {"id": ID_3D, "label": 5}], ["medium", "hard"]),
    ([{"video": f"{ID_2D_A}.mp4", "difficulty": 2.5}, {"id": ID_3D, "difficulty": 3.5}],
     ["medium", "hard"]),
    ({ID_2D_A: {"difficulty": {"label": "hard", "score": 9.1}}}, ["hard", None]),
])
def test_difficulty_table_formats(tmp_path, clip_files, table, expect):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D], difficulty=table)
    assert [s.difficulty for s in load_original(tmp_path, "sub")] == expect


def test_numeric_ratings_map_to_labels():
    assert [difficulty_label(r) for r in (1, 2, 3, 4, 5)] == \
        ["easy", "easy", "medium", "hard", "hard"]
    assert difficulty_label(None) is None
    for bad in (0, 6, "extreme", True, [], float("nan")):
        with pytest.raises(ValueError):
            difficulty_label(bad)


@pytest.mark.parametrize("table", [{ID_2D_A: "extreme"}, {ID_2D_A: 7},
                                   [{"difficulty": "easy"}], "easy"])
def test_bad_difficulty_table_names_the_file(tmp_path, clip_files, table):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A], difficulty=table)
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, str(d / "difficulty_table.json"))
    with pytest.raises(ValueError):
        read_difficulty_table(d / "difficulty_table.json")


def test_split_filter(tmp_path, clip_files):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D, ID_2D_B])
    make_split(tmp_path, "test", clip_files, [ID_3D], difficulty={ID_3D: 4})
    test = load_original(tmp_path, "test")
    assert [(s.scene_id, s.difficulty, s.dataset) for s in test] == \
        [(ID_3D, "hard", "visphybench/test")]
    assert len(load_original(tmp_path, "sub")) == 3


def test_metadata_lines_of_another_split_are_skipped(tmp_path, clip_files):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D], metadata=[
        {"scene_id": ID_2D_A, "split": "sub"}, {"scene_id": ID_3D, "splits": ["test"]}])
    assert [s.scene_id for s in load_original(tmp_path, "sub")] == [ID_2D_A]


def test_scene_ids_filter(tmp_path, clip_files):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D, ID_2D_B])
    scenes = load_original(tmp_path, "sub", scene_ids=[ID_2D_B, ID_2D_A])
    assert [s.scene_id for s in scenes] == [ID_2D_A, ID_2D_B]  # dataset order, not filter order
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub", scene_ids=[ID_2D_A, "task99999_000"])
    _one_line_error(info, "metadata.jsonl", "task99999_000")


def test_a_filtered_out_scene_is_not_probed(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D])
    (d / "videos" / f"{ID_3D}.mp4").write_bytes(b"broken")
    assert [s.scene_id for s in load_original(tmp_path, "sub", scene_ids=[ID_2D_A])] == [ID_2D_A]


def test_without_a_detection_folder_scenes_have_no_detection(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A])
    shutil.rmtree(d / "detection_json")
    (scene,) = load_original(tmp_path, "sub")
    assert scene.detection_path is None and scene.detection is None


# --------------------------------------------------------------------------- errors


def test_missing_video_names_the_file(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D])
    (d / "videos" / f"{ID_3D}.mp4").unlink()
    with pytest.raises(FileNotFoundError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, str(d / "videos" / f"{ID_3D}.mp4"), "metadata.jsonl line 2")


def test_malformed_detection_json_names_the_file_when_read(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A])
    det = d / "detection_json" / f"{ID_2D_A}_frame_01.json"
    det.write_text('{"objects": [\n  {"id": "red_ball",}\n]}')
    (scene,) = load_original(tmp_path, "sub")  # lazy: loading does not read detections
    with pytest.raises(ValueError) as info:
        scene.detection
    _one_line_error(info, str(det), "line 2")


def test_missing_detection_file_in_an_existing_folder_names_it(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D])
    det = d / "detection_json" / f"{ID_3D}_frame_01.json"
    det.unlink()
    with pytest.raises(FileNotFoundError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, str(det))


def test_malformed_metadata_line_names_file_and_line(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A, ID_3D])
    meta = d / "metadata.jsonl"
    meta.write_text(json.dumps({"scene_id": ID_2D_A}) + "\n\n" + '{"scene_id": "14_tmpl_14"\n')
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, f"{meta} line 3")


@pytest.mark.parametrize("line, needle", [
    ('["task10063_000"]', "expected a JSON object"),
    ('{"caption": "no id"}', "no scene id"),
    ('{"scene_id": 12}', "non-empty string"),
])
def test_metadata_line_without_a_usable_id(tmp_path, clip_files, line, needle):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A], metadata=None)
    (d / "metadata.jsonl").write_text(line + "\n")
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, f"{d / 'metadata.jsonl'} line 1", needle)


def test_duplicate_metadata_line_is_an_error(tmp_path, clip_files):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A],
               metadata=[{"scene_id": ID_2D_A}, {"video": f"{ID_2D_A}.mp4"}])
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, "metadata.jsonl line 2", "listed twice")


def test_missing_split_dir_names_it(tmp_path, clip_files):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A])
    with pytest.raises(FileNotFoundError) as info:
        load_original(tmp_path, "test")
    _one_line_error(info, str(tmp_path / "test"))


def test_bad_scene_id_names_the_file(tmp_path, clip_files):
    make_split(tmp_path, "sub", clip_files, [ID_2D_A],
               metadata=[{"scene_id": ID_2D_A}, {"scene_id": "ball_drop_01"}])
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, "metadata.jsonl line 2", "ball_drop_01")


def test_bad_scene_id_in_the_videos_listing_names_the_video(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A], metadata=None)
    shutil.copyfile(clip_files[ID_2D_A], d / "videos" / "Task10063_0.mp4")
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, str(d / "videos" / "Task10063_0.mp4"))


def test_unreadable_video_names_the_file(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A])
    video = d / "videos" / f"{ID_2D_A}.mp4"
    video.write_bytes(b"\x00not an mp4" * 20)
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, str(video), "unreadable video")


def test_malformed_difficulty_json_names_the_file(tmp_path, clip_files):
    d = make_split(tmp_path, "sub", clip_files, [ID_2D_A])
    (d / "difficulty_table.json").write_text('{"task10063_000": "easy",,}')
    with pytest.raises(ValueError) as info:
        load_original(tmp_path, "sub")
    _one_line_error(info, str(d / "difficulty_table.json"))


def test_generated_ids_in_the_published_layout_load_with_their_template(tmp_path, clip_files):
    """visphy's own ids (no ``_`` in them) laid out like the published data: each loads with
    its template (``3d-t004``), where the template rule for published ids raised IndexError."""
    ids = {"vpb3-s0-3d-t004-v02": clip_files[ID_3D], "vpb3-s0-2d-t017-v01": clip_files[ID_2D_A]}
    make_split(tmp_path, "sub", ids, sorted(ids), difficulty=None, metadata=None)
    scenes = load_original(tmp_path, "sub")
    assert [(s.scene_id, s.template_id, s.dim) for s in scenes] == [
        ("vpb3-s0-2d-t017-v01", "2d-t017", "2d"), ("vpb3-s0-3d-t004-v02", "3d-t004", "3d")]
