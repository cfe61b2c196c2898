"""Write the generated VisPhyBench to disk: the VisPhyBench layout plus visphy's exact ground truth.

``<data_dir>/visphybench-v<version>-seed<seed>[-lossless]/`` holds ``catalogue.json`` (every scene's
annotated spec, labels, splits, rejection counts: simulated, not rendered; for the default seed
copied from the catalogue shipped with visphy, `visphy_plugins.datasets.visphybench.shipped`),
and per rendered scene
``videos/<id>.mp4``, ``detection_json/<id>_frame_01.json``, ``keyframes/<id>_frame_01.png`` and
``_frame_10.png``, ``specs/<id>.json``, ``trajectories/<id>.npz`` and ``meta/<id>.json`` (written
last: its presence means the scene is complete). ``metadata.jsonl``, ``difficulty_table.json``
and the datasheet are rewritten after every build; the contact sheet and preview once every
scene is rendered. Scenes are rendered on demand, so ``split=mini`` renders four scenes, and an
interrupted build resumes where it stopped. Nothing depends on the clock: builds are byte-identical.

Any number of processes may build into one root at once (runs, studies, ``visphy build-dataset``
sharing a home). Each once-only step happens under an ``flock`` (`exclusive`) and is checked
again inside it, so whoever comes next finds it done and only reads:

- ``catalogue.json.lock``: writing the catalogue, shipped or simulated (one process writes);
- ``meta/<id>.json.lock``: rendering that scene. A lock per scene, not per build: a process that
  needs four scenes waits only for those four, never for another process's 209-scene build, and
  two concurrent full builds each skip what the other has finished;
- ``build_times.json.lock``: the read-modify-write of ``build_times.json``;
- ``metadata.jsonl.lock``: reading every ``meta/<id>.json`` and writing the indexes from them
  (``metadata.jsonl``, ``difficulty_table.json``, the datasheet, contact sheet and preview). Each
  is a deterministic function of the catalogue and the scenes present, written by atomic
  replace, so no reader sees a torn file; the lock makes the last writer one that saw every
  scene rendered before it, so a slower process never overwrites a longer index with a shorter.
"""

from __future__ import annotations

import io
import json
import logging
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from visphy_core.api.media import PUBLISHED_CRF, png_bytes
from visphy_core.api.selection import Traits
from visphy_core.api.storage import atomic_write, exclusive, lock_path
from visphy_plugins.datasets.visphybench.catalogue import (
    GENERATOR_VERSION,
    Catalogue,
    Entry,
)
from visphy_plugins.datasets.visphybench.catalogue import build_catalogue as simulate_catalogue

#: The written files' version (= the generator's): a build of another version is never mixed
#: with this one (each version has its own folder, `dataset_root`).
BUILDER_VERSION = f"visphy-bench/{GENERATOR_VERSION}"
KEY_FRAMES = (1, 10)
DATASET_NAME = "visphybench"
#: What the published clips are (H.264 yuv420p, crf 23); ``lossless`` builds are exact RGB
#: (for engine conformance: a reference program can then be compared pixel for pixel).
GT_CRF = PUBLISHED_CRF

log = logging.getLogger("visphy.bench")
#: Why `_read_catalogue` found no catalogue, besides an unreadable file.
_MISSING, _STALE = "missing", "stale"


def dataset_root(data_dir: Path, seed: int = 0, version: int = GENERATOR_VERSION,
                 lossless: bool = False) -> Path:
    """``<data_dir>/visphybench-v<version>-seed<seed>[-lossless]``; version 2 builds (before
    scene ids had their own namespace) live in ``visphybench-seed<seed>``."""
    if version <= 2:
        return Path(data_dir) / f"{DATASET_NAME}-seed{seed}"
    return Path(data_dir) / (f"{DATASET_NAME}-v{version}-seed{seed}"
                             + ("-lossless" if lossless else ""))


def json_bytes(obj) -> bytes:
    return (json.dumps(obj, indent=1) + "\n").encode()


def _npz_bytes(rollout, dim: str) -> bytes:
    buf = io.BytesIO()
    arrays = {"body_ids": np.array(rollout.body_ids, dtype=str),
              "frame_poses": rollout.frame_poses, "step_poses": rollout.step_poses,
              "frame_steps": rollout.frame_steps, "frame_times_s": rollout.frame_times_s}
    if dim == "2d":
        arrays["pose_layout"] = np.array(["x_px", "y_px", "angle_rad"])
    else:
        arrays["pose_layout"] = np.array(["x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"])
    np.savez(buf, **arrays)
    return buf.getvalue()


# ------------------------------------------------------------------------------ catalogue


def load_or_build_catalogue(root: Path, seed: int, progress: bool = True,
                            workers: int = 2, rebuild: bool = False) -> Catalogue:
    """The catalogue of ``root``, written once per root: under its lock, and checked again
    inside it, so of concurrent callers one writes it and the others read its file. It comes
    from `build_catalogue` (the shipped copy for the default seed, else simulated). A
    ``catalogue.json`` of another builder version or seed is replaced (its scenes with it); one
    that does not parse is named in one warning and rebuilt (it is a deterministic function of
    the generator, so the scenes already rendered stay valid). ``rebuild``: simulate it here
    whatever is on disk or shipped (``build-dataset --rebuild-catalogue``); a scene whose entry
    comes out different is rendered again."""
    path = root / "catalogue.json"
    found = _read_catalogue(path, seed)
    if isinstance(found, Catalogue) and not rebuild:
        return found
    with exclusive(lock_path(path), f"the benchmark catalogue {path}"):
        found = _read_catalogue(path, seed)
        if isinstance(found, Catalogue):
            if not rebuild:  # another process wrote it while this one waited
                return found
        elif found == _STALE:
            for stale in (root / "meta").glob("*.json"):  # built by another builder version
                stale.unlink()
        elif found != _MISSING:
            log.warning("%s is unreadable (%s): rebuilding it", path, found)
        catalogue = _build_catalogue_file(root, path, seed, progress, workers, rebuild)
        if isinstance(found, Catalogue):
            _drop_changed_scenes(root, found, catalogue)
        return catalogue


def _read_catalogue(path: Path, seed: int) -> Catalogue | str:
    """The catalogue in ``path``, or why not: `_MISSING`, `_STALE` (another builder version or
    seed), else what is wrong with the file (truncated, garbage, not a catalogue)."""
    try:
        data = json.loads(path.read_bytes())
    except FileNotFoundError:
        return _MISSING
    except (OSError, ValueError) as exc:
        return f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
    return _parse_catalogue(data, seed)


def _parse_catalogue(data, seed: int) -> Catalogue | str:
    """A parsed ``catalogue.json`` as a `Catalogue`, or `_STALE`, or what is wrong with it."""
    try:
        if data.get("builder") != BUILDER_VERSION or data.get("seed") != seed:
            return _STALE
        entries = [Entry(spec=s["spec"], digest=s["digest"], attempts=s["attempts"],
                         rejected=s["rejected"]) for s in data["scenes"]]
        return Catalogue(seed=seed, entries=entries, rejected=data["rejected"],
                         splits=data["splits"])
    except (AttributeError, KeyError, TypeError) as exc:
        return f"not a catalogue: {type(exc).__name__}: {' '.join(str(exc).split())[:200]}"


def catalogue_bytes(catalogue: Catalogue) -> bytes:
    """What ``catalogue.json`` holds: the same bytes for the same catalogue."""
    return json_bytes({
        "builder": BUILDER_VERSION, "seed": catalogue.seed, "splits": catalogue.splits,
        "rejected": catalogue.rejected,
        "scenes": [{"spec": e.spec, "digest": e.digest, "attempts": e.attempts,
                    "rejected": e.rejected} for e in catalogue.entries]})


def shipped_catalogue(seed: int) -> Catalogue | None:
    """The catalogue shipped with visphy for ``seed`` and this builder version; None when none
    is shipped for it, or (with one warning saying why) when the shipped file is damaged."""
    from visphy_plugins.datasets.visphybench.shipped import ShippedDamaged, shipped_bytes

    try:
        raw = shipped_bytes(seed)
        if raw is None:
            return None
        try:
            found = _parse_catalogue(json.loads(raw), seed)
        except ValueError as exc:
            raise ShippedDamaged(f"not JSON: {exc}") from None
        if not isinstance(found, Catalogue):
            raise ShippedDamaged("not a catalogue of this builder and seed"
                                 if found == _STALE else found)
        return found
    except ShippedDamaged as exc:
        log.warning("the catalogue shipped with visphy for seed %d is unusable (%s): "
                    "simulating it instead", seed, exc)
        return None


def build_catalogue(seed: int = 0, workers: int = 2, progress: bool = True) -> Catalogue:
    """The catalogue of ``seed``: the copy shipped with visphy when there is one for this seed
    and generator version (`shipped_catalogue`), else simulated (`simulate_catalogue`: every
    scene drawn, simulated and screened, one to two minutes on two cores)."""
    shipped = shipped_catalogue(seed)
    if shipped is not None:
        return shipped
    return simulate_catalogue(seed=seed, workers=workers, progress=progress)


def _build_catalogue_file(root: Path, path: Path, seed: int, progress: bool,
                          workers: int, simulate: bool = False) -> Catalogue:
    """Make the catalogue (``simulate``: never the shipped copy) and write it atomically (the
    caller holds its lock)."""
    start = time.perf_counter()
    if simulate:
        catalogue = simulate_catalogue(seed=seed, workers=workers, progress=progress)
    else:
        catalogue = build_catalogue(seed=seed, workers=workers, progress=progress)
    atomic_write(path, catalogue_bytes(catalogue))
    _note_time(root, "catalogue_s", time.perf_counter() - start)
    return catalogue


def _drop_changed_scenes(root: Path, before: Catalogue, after: Catalogue) -> None:
    """Remove the rendered mark (``meta/<id>.json``) of every scene whose entry differs between
    two catalogues of one root, so that it is rendered again from the new one."""
    old = {e.spec["scene_id"]: (e.spec, e.digest) for e in before.entries}
    new = {e.spec["scene_id"]: (e.spec, e.digest) for e in after.entries}
    changed = sorted(sid for sid in old.keys() | new.keys() if old.get(sid) != new.get(sid))
    dropped = [sid for sid in changed if (root / "meta" / f"{sid}.json").is_file()]
    for sid in dropped:
        (root / "meta" / f"{sid}.json").unlink()
    if changed:
        log.warning("the rebuilt catalogue of %s differs from the one it replaces in %d scene(s)"
                    "%s", root, len(changed),
                    f"; {len(dropped)} rendered one(s) will be rendered again" if dropped else "")


def _note_time(root: Path, key: str, seconds: float) -> None:
    """Record one build time in ``build_times.json``: a read-modify-write, so under its lock
    (concurrent builds each add their own key, none is lost)."""
    path = root / "build_times.json"
    with exclusive(lock_path(path), str(path)):
        times = _read_times(root)
        times[key] = round(seconds, 2)
        atomic_write(path, json_bytes(times))


def _read_times(root: Path) -> dict:
    """``build_times.json``; empty when missing or unreadable (it only informs the datasheet)."""
    try:
        times = json.loads((root / "build_times.json").read_bytes())
    except (OSError, ValueError):
        return {}
    return times if isinstance(times, dict) else {}


# ------------------------------------------------------------------------------ one scene


def _simulate_checked(spec: dict, digest: str):
    if spec["dim"] == "2d":
        from visphy_plugins.physics.box2d import simulate_2d, trajectory_digest

        rollout = simulate_2d(spec)
        got = trajectory_digest(rollout)
    else:
        from visphy_plugins.physics.cannon import simulate_3d, trajectory_digest_3d

        rollout = simulate_3d(spec)
        got = trajectory_digest_3d(rollout)
    if got != digest:
        raise RuntimeError(f"{spec['scene_id']}: re-simulation gave trajectory digest {got[:12]}, "
                           f"the catalogue says {digest[:12]} (the simulation differs here from "
                           "where the catalogue was made: `visphy build-dataset "
                           "--rebuild-catalogue` simulates it on this machine)")
    return rollout


def _frames_and_detection(spec: dict, rollout, pool) -> tuple[np.ndarray, dict]:
    if spec["dim"] == "2d":
        from visphy_plugins.datasets.visphybench.detection import detection_from_spec
        from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d

        return (render_clip_2d(spec, rollout.frame_poses),
                detection_from_spec(spec, rollout.frame_poses[0]))
    from visphy_plugins.datasets.visphybench.detection3d import detection_from_spec_3d
    from visphy_plugins.datasets.visphybench.render3d import render_clip_3d

    return (render_clip_3d(spec, rollout.frame_poses, pool),
            detection_from_spec_3d(spec, rollout.frame_poses[0]))


def clip_of(spec: dict) -> tuple[float, int, int, int]:
    """(fps, n_frames, width, height) of a scene's reference clip."""
    w = spec["world"]
    if spec["dim"] == "2d":
        width, height = w["units"]["canvas_px"]
    else:
        width, height = spec["camera"]["width"], spec["camera"]["height"]
    return float(w["video_fps"]), int(w["n_frames"]), int(width), int(height)


def write_scene(entry: Entry, root: Path, pool=None, lossless: bool = False) -> dict:
    """Simulate (checking the catalogue digest), render and write one scene; returns its meta.
    The clip is encoded like the published ones (crf 23) or, ``lossless``, exactly."""
    from visphy_core.api.media import encode_video

    spec = json.loads(json.dumps(entry.spec))
    sid = spec["scene_id"]
    rollout = _simulate_checked(spec, entry.digest)
    spec["ground_truth"]["trajectory"] = f"trajectories/{sid}.npz"
    frames, detection = _frames_and_detection(spec, rollout, pool)
    fps, n_frames, width, height = clip_of(spec)
    if frames.shape != (n_frames, height, width, 3):
        raise RuntimeError(
            f"{sid}: rendered {frames.shape}, expected {(n_frames, height, width, 3)}")
    encode_video(frames, root / "videos" / f"{sid}.mp4", fps, crf=GT_CRF, lossless=lossless)
    for k in KEY_FRAMES:
        atomic_write(root / "keyframes" / f"{sid}_frame_{k:02d}.png", png_bytes(frames[k - 1]))
    atomic_write(root / "detection_json" / f"{sid}_frame_01.json", json_bytes(detection))
    atomic_write(root / "specs" / f"{sid}.json", json_bytes(spec))
    atomic_write(root / "trajectories" / f"{sid}.npz", _npz_bytes(rollout, spec["dim"]))
    meta = {"scene_id": sid, "template_id": spec.get("template_id"),
            # the published template this scene imitates: none does (visphy's templates are its
            # own, in the published families' style), so the column is always null
            "imitates": None,
            "generator_version": GENERATOR_VERSION, "encoding": (
                "h264rgb-lossless" if lossless else f"h264-yuv420p-crf{GT_CRF}"),
            "dim": spec["dim"],
            "family": spec.get("family"), "splits": spec.get("splits", []),
            "difficulty": spec["difficulty"]["label"], "fps": fps, "n_frames": n_frames,
            "width": width, "height": height, "digest_sha256": entry.digest,
            "categories": sorted({o["category"] for o in detection["objects"]}),
            "look": look_stats(frames, detection),
            "n_objects_by_category": _count(o["category"] for o in detection["objects"])}
    atomic_write(root / "meta" / f"{sid}.json", json_bytes(meta))
    return meta


def look_stats(frames: np.ndarray, detection: dict) -> dict:
    """What the clip looks like, for the datasheet's comparison with the published clips: the
    red ball's radius in frame 1 (px; from the detection) and the share of non-white pixels
    (any channel below 250) per frame: median, min and max over the clip."""
    nonwhite = (frames.min(axis=3) < 250).mean(axis=(1, 2))
    red = next((o for o in detection["objects"] if o.get("id") == "red_ball"), None)
    radius = (red or {}).get("size", {}).get("radius_pixels")
    return {"red_ball_radius_px": None if radius is None else round(float(radius), 2),
            "nonwhite_frac": {"median": round(float(np.median(nonwhite)), 5),
                              "min": round(float(nonwhite.min()), 5),
                              "max": round(float(nonwhite.max()), 5)},
            "n_objects": len(detection["objects"])}


def _count(items) -> dict[str, int]:
    out: dict[str, int] = {}
    for item in items:
        out[item] = out.get(item, 0) + 1
    return dict(sorted(out.items()))


def _meta_path(root: Path, entry: Entry) -> Path:
    """``meta/<id>.json``: written last, its presence means the scene is complete."""
    return root / "meta" / f"{entry.spec['scene_id']}.json"


def _render_missing(entry: Entry, root: Path, pool=None, lossless: bool = False) -> dict | None:
    """`write_scene` unless the scene is complete; returns its meta, or None when it was. Under
    the scene's lock, checked again inside it: of processes rendering one scene at once, one
    writes it and the others find its meta and skip it."""
    meta = _meta_path(root, entry)
    if meta.is_file():
        return None
    with exclusive(lock_path(meta), f"scene {entry.spec['scene_id']} of {root}"):
        if meta.is_file():
            return None
        return write_scene(entry, root, pool, lossless=lossless)


def _write_2d(args: tuple[Entry, str, bool]) -> dict | None:
    entry, root, lossless = args
    return _render_missing(entry, Path(root), lossless=lossless)


# ------------------------------------------------------------------------------ whole builds


def _render(entries: list[Entry], root: Path, progress: bool, workers: int,
            lossless: bool = False) -> None:
    from visphy_core.api.progress import track as _track  # bars on a terminal, lines in a log

    two_d = [e for e in entries if e.spec["dim"] == "2d"]
    three_d = [e for e in entries if e.spec["dim"] == "3d"]
    if two_d:
        if workers > 1 and len(two_d) > 1:
            with ProcessPoolExecutor(max_workers=workers) as ex:
                done = ex.map(_write_2d, [(e, str(root), lossless) for e in two_d])
                for _ in _track(done, len(two_d), "rendering 2D scenes", progress):
                    pass
        else:
            for e in _track(two_d, len(two_d), "rendering 2D scenes", progress):
                _render_missing(e, root, lossless=lossless)
    if three_d:
        from visphy_core.api.sandbox import BrowserPool

        with BrowserPool(untrusted=False) as pool:  # visphy's own reference pages
            for e in _track(three_d, len(three_d), "rendering 3D scenes", progress):
                _render_missing(e, root, pool, lossless=lossless)


def _built_metas(root: Path, catalogue: Catalogue) -> list[dict]:
    metas = []
    for e in catalogue.entries:
        path = _meta_path(root, e)
        if path.is_file():
            metas.append(json.loads(path.read_text()))
    return metas


def _update_indexes(root: Path, catalogue: Catalogue) -> None:
    """Rewrite the indexes from the scenes present now, under the indexes' lock: the scenes
    read and the files written are one step, so the last writer has seen every scene that any
    earlier writer saw."""
    with exclusive(lock_path(root / "metadata.jsonl"), f"the indexes of {root}"):
        times = _read_times(root)
        full_build = (times.get("catalogue_s", 0.0) + times["render_all_s"]
                      if "render_all_s" in times else None)
        _write_indexes(root, catalogue, _built_metas(root, catalogue), full_build)


def _write_indexes(root: Path, catalogue: Catalogue, metas: list[dict],
                   build_seconds: float | None) -> None:
    from visphy_plugins.datasets.visphybench.datasheet import write_datasheet

    atomic_write(root / "metadata.jsonl", "".join(json.dumps(m) + "\n" for m in metas).encode())
    table = {e.spec["scene_id"]: {"difficulty": e.spec["difficulty"]["label"],
                                  "score": e.spec["difficulty"]["score"],
                                  "features": e.spec["difficulty"]["features"],
                                  "splits": e.spec.get("splits", [])}
             for e in catalogue.entries}
    atomic_write(root / "difficulty_table.json", json_bytes(table))
    if len(metas) == len(catalogue.entries):
        write_datasheet(root, metas, catalogue.rejected, build_seconds)
        _write_previews(root, metas)


def _write_previews(root: Path, metas: list[dict]) -> None:
    from PIL import Image

    from visphy_core.api.media import decode_video
    from visphy_plugins.datasets.visphybench.preview import write_contact_sheet, write_preview

    firsts = [(m["scene_id"], np.asarray(Image.open(
        root / "keyframes" / f"{m['scene_id']}_frame_01.png").convert("RGB"))) for m in metas]
    write_contact_sheet(firsts, root / "contact_sheet.png")
    picks = metas[:: max(1, len(metas) // 16)][:16]
    write_preview([(m["scene_id"], decode_video(root / "videos" / f"{m['scene_id']}.mp4")[0])
                   for m in picks], root / "preview.mp4")


def split_entries(catalogue: Catalogue, split: str | None) -> list[Entry]:
    """The entries of ``split`` (None: every scene), in catalogue order; ``ValueError`` naming
    the valid splits for an unknown one."""
    if split is None:
        return list(catalogue.entries)
    if split not in catalogue.splits:
        raise ValueError(f"the generated benchmark has no split {split!r}; valid: "
                         f"{', '.join(sorted(catalogue.splits))}")
    members = set(catalogue.splits[split])
    return [e for e in catalogue.entries if e.spec["scene_id"] in members]


def entry_traits(entry: Entry) -> Traits:
    """What `visphy_core.api.selection` knows of a catalogue entry (the same as of its loaded
    `Scene`): id, dimension, difficulty label, template."""
    spec = entry.spec
    template = spec.get("template_id")
    return Traits(scene_id=spec["scene_id"], dim=spec.get("dim"),
                  difficulty=(spec.get("difficulty") or {}).get("label"),
                  template=None if template is None else str(template))


def render_scenes(root: Path, catalogue: Catalogue, split: str | None = None,
                  scenes: list[str] | None = None, progress: bool = True, workers: int = 2,
                  lossless: bool = False) -> None:
    """Render every scene of ``split`` (default: all) not rendered yet, or only ``scenes`` of
    it, then rewrite the indexes."""
    start = time.perf_counter()
    wanted = split_entries(catalogue, split)
    if scenes:
        named = set(scenes)
        wanted = [e for e in wanted if e.spec["scene_id"] in named]
    todo = [e for e in wanted if not _meta_path(root, e).is_file()]
    if todo:
        _render(todo, root, progress, workers, lossless=lossless)
        if not scenes:  # a few scenes' time is no split's build time
            _note_time(root, f"render_{split or 'all'}_s", time.perf_counter() - start)
    if todo or not (root / "metadata.jsonl").is_file():  # nothing new: the indexes stand
        _update_indexes(root, catalogue)


def build_dataset(data_dir: Path, seed: int = 0, split: str | None = None,
                  progress: bool = True, workers: int = 2, lossless: bool = False,
                  scenes: list[str] | None = None, rebuild_catalogue: bool = False) -> Path:
    """Make sure every scene of ``split`` (default: all) is rendered; returns the dataset root
    (this generator version's; ``lossless``: its exact-RGB twin build). ``scenes``: only
    those scenes of it (a run's selection, the ``render`` command's one scene).
    ``rebuild_catalogue``: simulate the catalogue here rather than use the shipped one or the
    one on disk."""
    root = dataset_root(data_dir, seed, lossless=lossless)
    catalogue = load_or_build_catalogue(root, seed, progress=progress, workers=workers,
                                        rebuild=rebuild_catalogue)
    render_scenes(root, catalogue, split, scenes, progress=progress, workers=workers,
                  lossless=lossless)
    return root


ensure_dataset = build_dataset
