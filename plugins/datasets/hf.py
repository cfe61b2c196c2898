"""``dataset=hf dataset.root=DIR``: a dataset exported as a Hugging Face ``datasets`` folder,
written (`HFDataset.export`, ``visphy export-dataset --format hf``) and read back here, so
the layout has one owner. Layout of ``DIR``::

    README.md                       dataset card: YAML header (configs, dataset_info) + datasheet
    data/<split>-00000-of-00001.parquet   one row per scene (`COLUMNS`)
    videos/<scene_id>.mp4           the ground-truth clip, byte for byte
    trajectories/<scene_id>.npz     the ground-truth trajectory (generated scenes)

The key frames (``frame_01``, ``frame_10``: Hugging Face Image structs ``{bytes, path}``),
the detection and the scene spec are in the Parquet rows, as the exported files' exact bytes.
Reading needs pyarrow only: those bytes are written once under
``<paths.data_dir>/hf/<folder>-<digest>/`` (keyed by the split file's content), so a run on
the folder reads the very files a run on the source dataset read, and gives the same rows.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from visphy_core.api.dataset import Dataset, FinishedRun, GroundTruth
from visphy_core.api.errors import ConfigError, UserError
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.media import ClipInfo
from visphy_core.api.scene import Scene
from visphy_core.api.storage import atomic_write, files
from visphy_plugins.datasets.layout import locate_in_layout

KEY_FRAMES = (1, 10)
#: One row per scene: name → (Hugging Face feature, what it holds).
COLUMNS: dict[str, tuple[dict, str]] = {
    "scene_id": ({"dtype": "string", "_type": "Value"}, "the scene's id"),
    "split": ({"dtype": "string", "_type": "Value"}, "the split this file is"),
    "dim": ({"dtype": "string", "_type": "Value"}, "2d or 3d"),
    "difficulty": ({"dtype": "string", "_type": "Value"}, "easy, medium or hard"),
    "template": ({"dtype": "string", "_type": "Value"}, "the template the scene comes from"),
    "source": ({"dtype": "string", "_type": "Value"}, "the build it was exported from"),
    "fps": ({"dtype": "float64", "_type": "Value"}, "the clip's frame rate"),
    "n_frames": ({"dtype": "int32", "_type": "Value"}, "the clip's frame count"),
    "width": ({"dtype": "int32", "_type": "Value"}, "the clip's width (px)"),
    "height": ({"dtype": "int32", "_type": "Value"}, "the clip's height (px)"),
    "frame_01": ({"_type": "Image"}, "key frame 1 (PNG), what the model sees first"),
    "frame_10": ({"_type": "Image"}, "key frame 10 (PNG), what the model sees second"),
    "detection": ({"dtype": "string", "_type": "Value"},
                  "the detection of frame 1 (JSON text): the object list in the prompt"),
    "spec": ({"dtype": "string", "_type": "Value"},
             "the scene spec (JSON text): world, bodies, materials, velocities, camera"),
    "ground_truth": ({"dtype": "string", "_type": "Value"},
                     "the spec's ground truth (JSON text): contact events, trajectory file"),
    "metadata": ({"dtype": "string", "_type": "Value"},
                 "the build's metadata line (JSON text): categories, families, look"),
    "video": ({"dtype": "string", "_type": "Value"}, "the clip, relative to the folder"),
    "trajectory": ({"dtype": "string", "_type": "Value"},
                   "the trajectory .npz, relative to the folder (null: none)"),
}
_SPLIT_NAME = re.compile(r"\w+(\.\w+)*")


def split_file(root: Path, split: str) -> Path:
    return root / "data" / f"{split}-00000-of-00001.parquet"


def _splits(root: Path) -> list[str]:
    found = (root / "data").glob("*-00000-of-00001.parquet")
    return sorted(p.name.split("-00000-of-")[0] for p in found)


def _schema():
    import pyarrow as pa

    image = pa.struct([("bytes", pa.binary()), ("path", pa.string())])
    types = {"fps": pa.float64(), "n_frames": pa.int32(), "width": pa.int32(),
             "height": pa.int32(), "frame_01": image, "frame_10": image}
    features = {name: feature for name, (feature, _) in COLUMNS.items()}
    meta = {"huggingface": json.dumps({"info": {"features": features}})}
    return pa.schema([(name, types.get(name, pa.string())) for name in COLUMNS], metadata=meta)


# ------------------------------------------------------------------------------ writing


def _text(path: Path | None) -> str | None:
    return None if path is None else files.read_bytes(path, kind="json").decode("utf-8")


def _frame(scene: Scene, index: int) -> dict:
    path = scene.keyframe_paths.get(index)
    if path is not None and path.is_file():
        data = files.read_bytes(path, kind="image")
    else:  # no key-frame file (the published layout): the frame decoded from the clip
        import io

        from PIL import Image

        buffer = io.BytesIO()
        Image.fromarray(scene.key_frame(index)).save(buffer, format="PNG")
        data = buffer.getvalue()
    return {"bytes": data, "path": f"{scene.scene_id}_frame_{index:02d}.png"}


def _metadata(scene: Scene) -> str | None:
    """The scene's line of its build's metadata.jsonl (generated datasets), if any."""
    index = scene.video_path.parent.parent / "metadata.jsonl"
    if not index.is_file():
        return None
    for line in index.read_text(encoding="utf-8").splitlines():
        if f'"{scene.scene_id}"' in line:
            try:
                meta = json.loads(line)
            except ValueError:
                continue
            if meta.get("scene_id") == scene.scene_id:
                return json.dumps(meta, sort_keys=True)
    return None


def _row(scene: Scene, split: str, root: Path) -> dict:
    import shutil

    if scene.load_error:
        raise UserError(f"export-dataset: scene {scene.scene_id} did not load: "
                        f"{scene.load_error}")
    video = f"videos/{scene.scene_id}.mp4"
    (root / "videos").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(scene.video_path, root / video)
    trajectory = None
    if scene.trajectory_path is not None and scene.trajectory_path.is_file():
        trajectory = f"trajectories/{scene.scene_id}.npz"
        (root / "trajectories").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(scene.trajectory_path, root / trajectory)
    spec = _text(scene.spec_path)
    truth = json.loads(spec).get("ground_truth") if spec else None
    c = scene.clip
    return {"scene_id": scene.scene_id, "split": split, "dim": scene.dim,
            "difficulty": scene.difficulty, "template": scene.template_id,
            "source": scene.dataset or None, "fps": float(c.fps), "n_frames": c.n_frames,
            "width": c.width, "height": c.height,
            **{f"frame_{k:02d}": _frame(scene, k) for k in KEY_FRAMES},
            "detection": _text(scene.detection_path), "spec": spec,
            "ground_truth": None if truth is None else json.dumps(truth, sort_keys=True),
            "metadata": _metadata(scene), "video": video, "trajectory": trajectory}


def _card(root: Path) -> str:
    """README.md: the YAML header `datasets` reads, what the columns hold, the datasheet."""
    import pyarrow.parquet as pq

    splits = _splits(root)
    tables = {s: pq.read_table(split_file(root, s), columns=["scene_id", "dim", "difficulty",
                                                               "metadata"]) for s in splits}
    features = [{"name": n, **({"dtype": "image"} if f["_type"] == "Image" else
                               {"dtype": f["dtype"]})} for n, (f, _) in COLUMNS.items()]
    header = {"configs": [{"config_name": "default", "data_files": [
                  {"split": s, "path": f"data/{s}-*.parquet"} for s in splits]}],
              "dataset_info": {"features": features, "splits": [
                  {"name": s, "num_bytes": split_file(root, s).stat().st_size,
                   "num_examples": tables[s].num_rows} for s in splits]},
              "tags": ["physics", "video", "multimodal", "visphy"]}
    import yaml

    out = ["---", yaml.safe_dump(header, sort_keys=False).rstrip(), "---", "",
           "# VisPhyBench (visphy export)", "",
           "Physics scenes for evaluating whether a multimodal model understands physics by "
           "writing a simulator (visphy): two key frames and an object "
           "list go in, a program that plays the whole clip comes out, and the rendered clip "
           "is scored against `videos/<scene_id>.mp4`. Exported by `visphy export-dataset "
           "--format hf`; `visphy dataset=hf dataset.root=<this folder>` runs on it.", "",
           "| split | scenes | 2D | 3D | easy | medium | hard |",
           "|---|---:|---:|---:|---:|---:|---:|"]
    entries: dict[str, dict] = {}
    for s, t in tables.items():
        d = t.to_pydict()
        out.append(f"| {s} | {t.num_rows} | {d['dim'].count('2d')} | {d['dim'].count('3d')} | "
                   + " | ".join(str(d["difficulty"].count(k)) for k in ("easy", "medium", "hard"))
                   + " |")
        for text in d["metadata"]:
            if text:
                meta = json.loads(text)
                entries[meta["scene_id"]] = meta
    out += ["", "| column | what |", "|---|---|"]
    out += [f"| `{n}` | {what} |" for n, (_, what) in COLUMNS.items()]
    out += ["", "```python", "from datasets import load_dataset",
            'ds = load_dataset("path/to/this/folder")',
            f"ds[{splits[0]!r}][0]['frame_01']  # a PIL image" if splits else "", "```"]
    datasheet = _datasheet(list(entries.values()))
    if datasheet:
        out += ["", datasheet.replace("# VisPhyBench datasheet", "## Datasheet", 1)
                .replace("\n## ", "\n### ")]
    return "\n".join(out).rstrip() + "\n"


def _datasheet(entries: list[dict]) -> str | None:
    """The generated benchmark's datasheet of the exported scenes (None: not generated)."""
    if not entries:
        return None
    from visphy_plugins.datasets.visphybench.datasheet import datasheet_stats, render_markdown

    try:
        return render_markdown(datasheet_stats(entries, {}))
    except (KeyError, ValueError):
        return None


# ------------------------------------------------------------------------------ reading


def _materialise(root: Path, split: str, table, data_dir: Path) -> Path:
    """The rows' key frames, detections and specs as files, once per split file content."""
    digest = hashlib.sha256(files.read_bytes(split_file(root, split), kind="jsonl")).hexdigest()
    out = Path(data_dir) / "hf" / f"{root.name}-{split}-{digest[:16]}"
    if (out / ".complete").is_file():
        return out
    for row in table.to_pylist():
        sid = row["scene_id"]
        for k in KEY_FRAMES:
            image = row.get(f"frame_{k:02d}") or {}
            if image.get("bytes"):
                atomic_write(out / "keyframes" / f"{sid}_frame_{k:02d}.png", image["bytes"])
        for name, path in (("detection", f"detection_json/{sid}_frame_01.json"),
                           ("spec", f"specs/{sid}.json")):
            if row.get(name) is not None:
                atomic_write(out / path, row[name].encode("utf-8"))
    atomic_write(out / ".complete", b"")
    return out


def _inside(root: Path, relative: str | None, sid: str) -> Path | None:
    if not relative:
        return None
    path = Path(relative)
    if path.is_absolute() or ".." in path.parts:
        raise ValueError(f"{root}: scene {sid} names {relative!r}, outside the folder")
    return root / path


def load_hf(root: Path, split: str, data_dir: Path) -> list[Scene]:
    """The scenes of ``split`` in file order (a scene with a bad row becomes a data_error)."""
    import pyarrow.parquet as pq

    path = split_file(root, split)
    refused = files.scan_tree(root)
    for name in ("data", "videos", "trajectories", str(path.relative_to(root))):
        if name in refused:
            raise files.ForeignFileError(f"refused to read {root / name}: it is {refused[name]}")
    table = pq.read_table(path)
    missing = [c for c in COLUMNS if c not in table.column_names]
    if missing:
        raise ValueError(f"{path}: not a visphy export (no column {', '.join(missing)})")
    files_dir = _materialise(root, split, table, data_dir)
    scenes = []
    for row in table.to_pylist():
        sid = row["scene_id"]
        load_error = None
        try:
            video = _inside(root, row["video"], sid)
            trajectory = _inside(root, row["trajectory"], sid)
        except ValueError as exc:
            load_error, video, trajectory = str(exc), root / "videos" / f"{sid}.mp4", None
        keyframes = {k: files_dir / "keyframes" / f"{sid}_frame_{k:02d}.png" for k in KEY_FRAMES
                     if (row.get(f"frame_{k:02d}") or {}).get("bytes")}
        scenes.append(Scene(
            scene_id=sid, dim=row["dim"],
            clip=ClipInfo(fps=row["fps"], n_frames=row["n_frames"], width=row["width"],
                          height=row["height"]),
            video_path=video,
            detection_path=(files_dir / "detection_json" / f"{sid}_frame_01.json"
                            if row["detection"] is not None else None),
            spec_path=files_dir / "specs" / f"{sid}.json" if row["spec"] is not None else None,
            trajectory_path=trajectory, keyframe_paths=keyframes,
            difficulty=row["difficulty"], template_id=row["template"],
            dataset=row["source"] or root.name, load_error=load_error))
    return scenes


class HFDataset(Dataset):
    name = "hf"
    description = ("a dataset exported as a Hugging Face `datasets` folder (visphy "
                   "export-dataset --format hf), read back with pyarrow")

    def _root_split(self, cfg: Any) -> tuple[Path, str]:
        root = cfg.get("root") if hasattr(cfg, "get") else None
        if not root:
            raise ConfigError("dataset=hf needs dataset.root=DIR (a folder written by visphy "
                              "export-dataset --format hf)")
        root = Path(str(root)).expanduser()
        splits = _splits(root) if (root / "data").is_dir() else []
        if not splits:
            raise ConfigError(f"dataset.root={root}: no data/<split>-00000-of-00001.parquet "
                              "(write one with visphy export-dataset --format hf -o DIR)")
        split = cfg.get("split")
        if split is None:
            if len(splits) > 1:
                raise ConfigError(f"dataset.root={root} has splits {', '.join(splits)}: "
                                  "choose one with dataset.split=...")
            return root, splits[0]
        if str(split) not in splits:
            raise ConfigError(f"dataset.split={split}: {root} has {', '.join(splits)}")
        return root, str(split)

    def load(self, cfg: Any, data_dir: Path, progress: bool = True) -> list[Scene]:
        root, split = self._root_split(cfg)
        return load_hf(root, split, Path(data_dir))

    def check(self, cfg: Any) -> None:
        self._root_split(OmegaConf.select(cfg, "dataset"))

    def locate_ground_truth(self, run: FinishedRun, scene_ids: list[str]) -> dict[str, GroundTruth]:
        return locate_in_layout(run, scene_ids)

    def export(self, scenes: list[Scene], root: Path, *, split: str) -> Path:
        """Write ``scenes`` as ``split`` of the folder ``root`` (that split replaced, the
        others kept) and rewrite its card; returns the split's Parquet file."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        if not _SPLIT_NAME.fullmatch(split):
            raise UserError(f"export-dataset: split {split!r} is not a Hugging Face split name "
                            "(letters, digits, underscores, dots)")
        root = Path(root)
        rows = [_row(scene, split, root) for scene in scenes]
        path = split_file(root, split)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.partial")
        pq.write_table(pa.Table.from_pylist(rows, schema=_schema()), tmp)
        tmp.replace(path)
        atomic_write(root / "README.md", _card(root).encode("utf-8"))
        return path


@hookimpl
def visphy_register_datasets(register):
    register(HFDataset.name, HFDataset)
