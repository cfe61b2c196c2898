"""Load the original VisPhyBench-Data layout (the Hugging Face dataset) into `Scene` objects.

Layout of one split, ``<root>/<split>/``::

    videos/<id>.mp4                    ground-truth clip (2D: 17 frames @ 5 fps, 3D: 75 @ 15 fps)
    detection_json/<id>_frame_01.json  detection context D of the first frame
    difficulty_table.json              difficulty per scene (optional)
    metadata.jsonl                     one JSON object per scene (optional; else the videos listing)

The loader is lenient about formats and strict about errors:

- a metadata line names its scene as ``scene_id``, ``id``, ``video_id`` or ``video`` (a file name
  such as ``task10063_000.mp4`` or ``videos/task10063_000.mp4`` is reduced to its id); a line
  with a ``split``/``splits`` field that does not include the split is skipped;
- ``difficulty_table.json`` is ``{id: label}``, ``{id: {"difficulty"|"label"|"rating"...: v}}``
  or a list of ``{"scene_id"|"id"|...: id, "difficulty"|"label"|...: v}``; labels are normalised to
  easy/medium/hard, numeric 1–5 ratings (or a list of ratings, averaged) map 1–2 → easy,
  3 → medium, 4–5 → hard (a non-integer mean is rounded half up: 2.5 → medium, 3.5 → hard);
- clip info (fps, frame count, size) comes from the container header, without decoding frames.

Every error is one line that names the offending file (and the line for ``metadata.jsonl``).
Key frames are not files in this layout: `Scene.key_frame` decodes them from the video.
"""

from __future__ import annotations

import json
import math
import os
import re
from fractions import Fraction
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from visphy_core.api.dataset import Dataset, FinishedRun, GroundTruth
from visphy_core.api.errors import ConfigError
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.media import ClipInfo
from visphy_core.api.scene import Scene, read_json
from visphy_core.api.storage import files
from visphy_plugins.datasets.layout import locate_in_layout

#: Keys under which a metadata line or a difficulty-table item names its scene, in priority order.
ID_KEYS = ("scene_id", "id", "video_id", "video")
#: Keys under which a difficulty-table value (or metadata line) holds the label or rating.
DIFFICULTY_KEYS = ("difficulty", "label", "difficulty_label", "level", "rating", "ratings",
                   "mean_rating")
LABELS = ("easy", "medium", "hard")
_VIDEO_SUFFIXES = (".mp4", ".webm", ".mkv", ".mov", ".avi")


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def scene_id_from(value: Any) -> str:
    """A scene id from an id or a video file name/path (``videos/task10063_000.mp4``)."""
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"scene id must be a non-empty string, got {value!r}")
    name = Path(value.strip()).name
    for suffix in _VIDEO_SUFFIXES:
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return name


def difficulty_label(value: Any) -> str | None:
    """Normalise a difficulty value to easy/medium/hard (None stays None).

    Accepts a label (any case), a 1–5 rating (number or numeric string), a list of ratings
    (averaged) or a dict holding one of `DIFFICULTY_KEYS`. Raises ValueError otherwise.
    """
    if value is None:
        return None
    if isinstance(value, dict):
        for key in DIFFICULTY_KEYS:
            if key in value:
                return difficulty_label(value[key])
        raise ValueError(f"no difficulty key ({', '.join(DIFFICULTY_KEYS)}) in {value!r}")
    if isinstance(value, bool):
        raise ValueError(f"difficulty {value!r} is not a label or a 1-5 rating")
    if isinstance(value, str):
        text = value.strip().lower()
        if text in LABELS:
            return text
        try:
            rating = float(text)
        except ValueError:
            raise ValueError(f"difficulty {value!r} is not easy/medium/hard or a 1-5 rating") \
                from None
        return difficulty_label(rating)
    if isinstance(value, (list, tuple)):
        if not value or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                for v in value):
            raise ValueError(f"difficulty ratings {value!r} are not a non-empty list of numbers")
        return difficulty_label(sum(value) / len(value))
    if isinstance(value, (int, float)):
        rating = float(value)
        if not math.isfinite(rating) or not 1 <= rating <= 5:
            raise ValueError(f"difficulty rating {value!r} is outside 1-5")
        level = math.floor(rating + 0.5)  # round half up: 2.5 -> 3, 3.5 -> 4
        return "easy" if level <= 2 else "medium" if level == 3 else "hard"
    raise ValueError(f"difficulty {value!r} is not a label or a 1-5 rating")


def _id_of(obj: dict) -> str | None:
    for key in ID_KEYS:
        if key in obj:
            return scene_id_from(obj[key])
    return None


def read_difficulty_table(path: Path) -> dict[str, str | None]:
    """``{scene_id: easy|medium|hard|None}`` from any accepted table format."""
    table = read_json(path)
    out: dict[str, str | None] = {}
    if isinstance(table, dict):
        items = list(table.items())
    elif isinstance(table, list):
        items = []
        for i, item in enumerate(table):
            if not isinstance(item, dict):
                raise ValueError(f"{path}: item {i} is not an object")
            try:
                sid = _id_of(item)
            except ValueError as exc:
                raise ValueError(f"{path}: item {i}: {exc}") from None
            if sid is None:
                raise ValueError(f"{path}: item {i} names no scene "
                                 f"(expected one of {', '.join(ID_KEYS)})")
            items.append((sid, {k: v for k, v in item.items() if k not in ID_KEYS}))
    else:
        raise ValueError(f"{path}: expected an object or a list, got {type(table).__name__}")
    for key, value in items:
        sid = scene_id_from(key)
        try:
            out[sid] = difficulty_label(value)
        except ValueError as exc:
            raise ValueError(_one_line(f"{path}: scene {sid}: {exc}")) from None
    return out


def probe_clip(path: Path) -> ClipInfo:
    """fps, frame count and size of a video from its container header (no frame is decoded)."""
    import av

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"missing video: {path}")
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise ValueError(f"unreadable video {path}: no video stream")
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.guessed_rate or stream.base_rate
            fps = float(Fraction(rate)) if rate else 0.0
            width = int(stream.codec_context.width or stream.width or 0)
            height = int(stream.codec_context.height or stream.height or 0)
            n_frames = int(stream.frames or 0)
            if n_frames == 0:  # header without a frame count (e.g. Matroska): count packets
                n_frames = sum(1 for packet in container.demux(stream) if packet.size)
    except (av.error.FFmpegError, OSError) as exc:  # type: ignore[attr-defined]
        raise ValueError(_one_line(f"unreadable video {path}: {exc}")) from None
    if n_frames <= 0:
        raise ValueError(f"unreadable video {path}: no frames")
    if not fps > 0 or not math.isfinite(fps):
        raise ValueError(f"unreadable video {path}: no frame rate in the header")
    if width <= 0 or height <= 0:
        raise ValueError(f"unreadable video {path}: no frame size in the header")
    return ClipInfo(fps=fps, n_frames=n_frames, width=width, height=height)


def scene_dim(scene_id: str) -> str:
    """Infer 2D/3D from a scene id: published VisPhyBench `taskNNNNN_NNN` is 2D, `NN_tmpl_NN`
    is 3D; visphy's generated `vpb<version>-s<seed>-<2d|3d>-t…-v…` says it."""
    generated = re.fullmatch(r"vpb\d+-s\d+-(2d|3d)-t\d+-v\d+", scene_id)
    if generated:
        return generated.group(1)
    if re.fullmatch(r"task\d{5}_\d{3}", scene_id):
        return "2d"
    if re.fullmatch(r"\d+_tmpl_\d+", scene_id):
        return "3d"
    raise ValueError(
        f"scene id {scene_id!r} is neither 2D (taskNNNNN_NNN) nor 3D (NN_tmpl_NN) nor a "
        "generated id (vpb3-s0-2d-t001-v00)"
    )


def default_template_id(scene_id: str) -> str:
    """Template of an id: ``task10063_000`` → ``10063``, ``14_tmpl_14`` → ``tmpl_14``, a
    generated id laid out like the published data ``vpb3-s0-3d-t004-v02`` → ``3d-t004``."""
    generated = re.fullmatch(r"vpb\d+-s\d+-(2d|3d)-(t\d+)-v\d+", scene_id)
    if generated:
        return f"{generated.group(1)}-{generated.group(2)}"
    if scene_dim(scene_id) == "2d":
        return scene_id[len("task"):].split("_")[0]
    return "tmpl_" + scene_id.rsplit("_", 1)[1]


def _read_metadata(path: Path, split: str) -> list[tuple[str, dict, str]]:
    """(scene_id, line object, where) per scene line of metadata.jsonl, in file order."""
    rows: list[tuple[str, dict, str]] = []
    seen: dict[str, int] = {}
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(_one_line(f"cannot read {path}: {exc}")) from None
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        where = f"{path} line {lineno}"
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"malformed JSON in {where}: {exc.msg} (column {exc.colno})") \
                from None
        if not isinstance(obj, dict):
            raise ValueError(f"{where}: expected a JSON object, got {type(obj).__name__}")
        try:
            sid = _id_of(obj)
        except ValueError as exc:
            raise ValueError(_one_line(f"{where}: {exc}")) from None
        if sid is None:
            raise ValueError(f"{where}: no scene id (expected one of {', '.join(ID_KEYS)})")
        splits = obj.get("splits", obj.get("split"))
        if isinstance(splits, str):
            splits = [splits]
        if isinstance(splits, list) and splits and split not in splits:
            continue
        if sid in seen:
            raise ValueError(f"{where}: scene {sid} is listed twice (first on line {seen[sid]})")
        seen[sid] = lineno
        rows.append((sid, obj, where))
    return rows


def load_original(root: Path, split: str, scene_ids: list[str] | None = None,
                  strict: bool = True) -> list[Scene]:
    """Scenes of one split of the original VisPhyBench-Data layout under ``root``.

    Order: metadata.jsonl order, or the sorted videos listing when there is no metadata.
    ``scene_ids`` keeps only those scenes (in that same order); an id the split does not have is
    an error. Detection: ``detection_json/<id>_frame_01.json``; when the split has no
    ``detection_json/`` folder at all, scenes carry no detection (``detection_path=None``), but a
    scene missing its file in an existing folder is an error.
    """
    root = Path(root)
    split_dir = root / split
    if not split_dir.is_dir():
        raise FileNotFoundError(f"missing split folder: {split_dir} (dataset root {root})")
    # a foreign tree: links, special files and oversized files are refused, never read
    files.entry_kind(split_dir, root)
    refused = files.scan_tree(split_dir)
    for name in ("metadata.jsonl", "difficulty_table.json", "videos", "detection_json"):
        if name in refused:
            raise files.ForeignFileError(f"refused to read {split_dir / name}: it is "
                                         f"{refused[name]}")
    videos_dir = split_dir / "videos"
    meta_path = split_dir / "metadata.jsonl"
    det_dir = split_dir / "detection_json"
    table_path = split_dir / "difficulty_table.json"

    if meta_path.is_file():
        rows = _read_metadata(meta_path, split)
    else:
        if not videos_dir.is_dir():
            raise FileNotFoundError(
                f"missing videos folder: {videos_dir} (and no {meta_path.name})")
        rows = [(p.stem, {}, str(p)) for p in sorted(videos_dir.iterdir())
                if p.is_file() and p.suffix.lower() == ".mp4" and not p.name.startswith(".")]

    dims: dict[str, str] = {}
    for sid, _, where in rows:
        try:
            dims[sid] = scene_dim(sid)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None

    if scene_ids is not None:
        wanted = list(dict.fromkeys(scene_ids))
        missing = [s for s in wanted if s not in dims]
        if missing:
            source = meta_path if meta_path.is_file() else videos_dir
            raise ValueError(f"{source}: split {split!r} has no scene(s) {', '.join(missing)}")
        keep = set(wanted)
        rows = [r for r in rows if r[0] in keep]

    difficulty = read_difficulty_table(table_path) if table_path.is_file() else {}
    has_detection = det_dir.is_dir()

    scenes: list[Scene] = []
    for sid, meta, where in rows:
        video = videos_dir / f"{sid}.mp4"
        detection = det_dir / f"{sid}_frame_01.json"
        clip, label, load_error = ClipInfo(fps=0.0, n_frames=0, width=0, height=0), None, None
        try:
            for path in (video, detection):
                why = refused.get(path.relative_to(split_dir).as_posix())
                if why:
                    raise files.ForeignFileError(f"refused to read {path}: it is {why}")
            if not video.is_file():
                raise FileNotFoundError(f"missing video for scene {sid} ({where}): {video}")
            clip = probe_clip(video)
            if has_detection and not detection.is_file():
                raise FileNotFoundError(f"missing detection JSON for scene {sid}: {detection}")
            if sid in difficulty:
                label = difficulty[sid]
            else:
                try:
                    label = difficulty_label(next((meta[k] for k in DIFFICULTY_KEYS
                                                   if k in meta), None))
                except ValueError as exc:
                    raise ValueError(_one_line(f"{where}: {exc}")) from None
        except (OSError, ValueError) as exc:
            if strict:
                raise
            load_error = _one_line(str(exc))
        template = meta.get("template_id", meta.get("template"))
        scenes.append(Scene(
            scene_id=sid, dim=dims[sid], clip=clip, video_path=video,
            detection_path=detection if has_detection else None,
            spec_path=None, trajectory_path=None, keyframe_paths={},
            difficulty=label,
            template_id=str(template) if template is not None else default_template_id(sid),
            dataset=f"visphybench/{split}", load_error=load_error))
    return scenes


class OriginalLayout(Dataset):
    """``dataset.source=original``: the published VisPhyBench-Data folders on disk."""

    name = "original"
    description = ("the published VisPhyBench-Data layout: <root>/<split>/videos, "
                   "detection_json, metadata.jsonl, difficulty_table.json")

    def load(self, cfg: Any, data_dir: Path, progress: bool = True) -> list[Scene]:
        if not cfg.root:
            raise ValueError("dataset.source=original needs dataset.root (the folder holding "
                             "<split>/videos; or set VISPHYBENCH_ROOT)")
        return load_original(Path(cfg.root), split=cfg.split or "sub", scene_ids=cfg.scenes,
                             strict=False)

    def check(self, cfg: Any) -> None:
        try:
            root = OmegaConf.select(cfg, "dataset.root", default=None)
        except Exception as exc:  # noqa: BLE001
            raise ConfigError(f"dataset.root: {exc}".splitlines()[0]) from None
        if not root:
            raise ConfigError("dataset=original needs dataset.root (the folder holding "
                              "<split>/videos), or set VISPHYBENCH_ROOT")
        if not Path(str(root)).is_dir():
            raise ConfigError(f"dataset.root={root} is not a directory (the folder holding "
                              f"<split>/videos; or set VISPHYBENCH_ROOT)")
        split = OmegaConf.select(cfg, "dataset.split", default=None) or "sub"
        if not (Path(str(root)) / str(split)).is_dir():
            present = sorted(p.name for p in Path(str(root)).iterdir() if p.is_dir()
                             and not p.name.startswith("."))
            more = f", … ({len(present) - 12} more)" if len(present) > 12 else ""
            raise ConfigError(f"dataset.split={split}: no folder {Path(str(root)) / str(split)}; "
                              f"folders in dataset.root: "
                              f"{', '.join(present[:12]) + more if present else 'none'}")


    def locate_ground_truth(self, run: FinishedRun, scene_ids: list[str]) -> dict[str, GroundTruth]:
        env = os.environ.get("VISPHYBENCH_ROOT")
        return locate_in_layout(run, scene_ids, [Path(env)] if env else [])


@hookimpl
def visphy_register_datasets(register):
    register(OriginalLayout.name, OriginalLayout)
