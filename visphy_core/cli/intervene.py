"""``python -m visphy_core intervene``: change named physical parameters of a scene, re-simulate,
render the original and the intervened scene side by side.

The starting spec is the ground truth's (``--gt``) or a run's S (``--run RUN_DIR``: the S of the
reply the scene kept, ``spec.json`` or a repair's ``spec.attempt2.json``, merged into the scene's
world exactly as the spec track merges it).
Both specs, original and intervened, go through the same path: simulated by visphy's physics
(`visphy_core.spec.spec_track`), replayed by the engine's trusted reference program and rendered
through the content-addressed render cache, like the variance normalisation's twin. The
original is re-simulated rather than read from the dataset, so that an intervention that changes
nothing gives frames identical to the original's, byte for byte.

The output folder holds ``original.mp4``, ``intervened.mp4``, ``side_by_side.mp4`` (original |
intervened, labelled, same fps and frame size per half), ``spec.original.json``,
``spec.intervened.json``, ``changes.json`` (parameter, object, old → new, the spec fields),
``effects.json`` (per dynamic body: final and largest displacement, first contact, contact
begins; both rollouts' contact events) and ``trajectory.{original,intervened}.npz`` (per-frame
and per-step poses). Bad input exits 2 with one line (`visphy_core.spec.intervene`).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
from pathlib import Path

import numpy as np

from visphy_core.cli.help import default_option, sibling_option
from visphy_core.infra.errors import UserError
from visphy_core.spec.intervene import (
    PARAMETERS,
    compare_rollouts,
    effect_lines,
    intervened_spec,
    parse_assignment,
)

LABEL_HEIGHT = 18


def _parser() -> argparse.ArgumentParser:
    home = os.environ.get("VISPHY_HOME", "visphy-out")
    p = argparse.ArgumentParser(
        prog="visphy intervene",
        description="Change physical parameters of a scene's spec (the ground truth's or a run's "
                    "S), re-simulate it and render original | intervened side by side.",
        epilog="parameters (SI units): " + "; ".join(
            f"{n} ({p.unit or 'no unit'}: {p.help})" for n, p in PARAMETERS.items())
        + ". PARAM=VALUE applies to every body (gravity: the world), PARAM.OBJECT=VALUE to one "
          "body; VALUE is a number, a vector 3,0 or xF (F times the current value).")
    p.add_argument("--scene", required=True, help="scene id, e.g. vpb3-s0-2d-t001-v00")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--run", help="a run directory: start from the model's S for the scene")
    source.add_argument("--gt", action="store_true", help="start from the ground-truth spec")
    p.add_argument("--set", dest="assignments", action="append", default=[], metavar="P=V",
                   required=True, help="a change, e.g. gravity=-20, friction=0.1, "
                                       "mass.red_ball=2, velocity.red_ball=3,0 (repeatable)")
    dataset = default_option("dataset")
    p.add_argument("--engine", default=None,
                   help="engine whose reference program renders both (default: the run's "
                        f"engine; with --gt {default_option('engine')})")
    p.add_argument("--dataset", default=None,
                   help=f"with --gt: the dataset config holding the scene (default: {dataset}; "
                        f"{sibling_option('dataset')} for any other scene of its source)")
    p.add_argument("-o", "--out", default=None,
                   help=f"output folder (default: {home}/interventions/<scene>_<time>)")
    p.add_argument("overrides", nargs="*", default=[], help="Hydra overrides, e.g. run.cache=false")
    return p


def intervene_command(argv: list[str]) -> int:
    from visphy_core.api.engine import RenderContract
    from visphy_core.api.registry import get_registry
    from visphy_core.config.check import check_overrides
    from visphy_core.execute.run_setup import _isolation
    from visphy_core.infra.cache import Cache

    args = _parser().parse_intermixed_args(argv)
    for text in args.assignments:
        parse_assignment(text)  # a bad parameter name fails before anything is loaded
    if not args.scene or any(c in args.scene for c in ",[]* "):
        raise UserError(f"--scene {args.scene!r}: name exactly one scene id")
    run_cfg = _run_config(args.run) if args.run else None
    engine_name = args.engine or (str(run_cfg.engine.name) if run_cfg
                                  else default_option("engine"))
    overrides = [f"engine={engine_name}", "tracking=none"]
    if args.gt:
        overrides += ([f"dataset={args.dataset}"] if args.dataset else []) + [
            f"dataset.scenes=[{args.scene}]"]
    (cfg,) = check_overrides(overrides + list(args.overrides), inputs=True)[:1]
    scene, base, source = (_gt_start(cfg, args.scene) if args.gt
                           else _run_start(Path(args.run), args.scene))
    intervened, changes = intervened_spec(base, args.assignments)

    engine = get_registry().get("engines", engine_name)(cfg.engine)
    if scene.dim == "3d" and not engine.supports_3d:
        raise UserError(f"engine {engine_name} draws 2D scenes only; {scene.scene_id} is 3D")
    out = Path(args.out) if args.out else Path(cfg.paths.root) / "interventions" / (
        f"{scene.scene_id}_{dt.datetime.now():%Y-%m-%d_%H-%M-%S}")
    out.mkdir(parents=True, exist_ok=True)
    cache = Cache(Path(cfg.paths.cache_dir).resolve(), enabled=bool(cfg.run.cache))
    contract = RenderContract.for_scene(scene, timeout_s=float(cfg.engine.timeout_s),
                                        seed=int(cfg.run.seed))
    _isolation(cfg)
    try:
        runs = {name: _simulate_and_render(scene, spec, name, engine, contract, cache, out)
                for name, spec in (("original", base), ("intervened", intervened))}
    finally:
        engine.close()
    labels = (f"original ({source})", "intervened: " + "; ".join(args.assignments))
    side = side_by_side(runs["original"][1], runs["intervened"][1], labels)
    from visphy_core.infra.video import encode_video

    encode_video(side, out / "side_by_side.mp4", contract.fps)
    effects = compare_rollouts(base, runs["original"][0], runs["intervened"][0])
    effects["events"] = {name: list(getattr(r[0], "events", []) or [])
                         for name, r in runs.items()}
    _write_json(out / "spec.original.json", base)
    _write_json(out / "spec.intervened.json", intervened)
    _write_json(out / "changes.json", {
        "scene_id": scene.scene_id, "dim": scene.dim, "source": source,
        "run": str(Path(args.run).resolve()) if args.run else None, "engine": engine_name,
        "changes": [c.to_json() for c in changes]})
    _write_json(out / "effects.json", effects)
    print(f"{scene.scene_id} ({scene.dim}, {source}), rendered by {engine_name}'s reference "
          "program")
    print("changes:\n" + "\n".join(f"  {c.describe()}" for c in changes))
    print("effects (dynamic bodies, most moved first):\n"
          + "\n".join(f"  {line}" for line in effect_lines(effects)))
    print(f"folder: {out}  ({', '.join(sorted(p.name for p in out.iterdir() if p.is_file()))})")
    return 0


def _run_config(run: str):
    from visphy_core.execute.run_scenes import read_run_config

    return read_run_config(Path(run))


def _gt_start(cfg, scene_id: str):
    from visphy_core.execute.datasets import load_dataset

    (scene,) = [s for s in load_dataset(cfg.dataset, Path(cfg.paths.data_dir).resolve(),
                                        progress=False) if s.scene_id == scene_id]
    if scene.spec is None:
        raise UserError(f"scene {scene_id} has no ground-truth spec to intervene on (only "
                        "generated benchmarks have one)")
    base = {k: v for k, v in scene.spec.items() if k != "splits"}  # the dataset writer's
    return scene, base, "ground truth"


def _run_start(run_dir: Path, scene_id: str):
    from visphy_core.api.scene import read_json
    from visphy_core.execute.run_scenes import load_run_scenes
    from visphy_core.results.layout import SPEC, attempt_file
    from visphy_core.results.run_dir import RunDir, kept_attempt
    from visphy_core.spec.spec_track import SpecTrackError, merged_spec

    run = RunDir(run_dir)
    scene_dir = run.scene_dir(scene_id)
    if not scene_dir.is_dir():
        raise UserError(f"{run_dir} has no scene {scene_id}")
    # the S the row's spec track used: that of the reply the scene kept (a repair's, if any)
    row = next((r for r in run.read_rows()[0] if r.scene_id == scene_id), None)
    attempt = kept_attempt(scene_dir, row.attempts if row is not None else 1) or 1
    path = scene_dir / attempt_file(SPEC, attempt, "json")
    if not path.is_file():
        raise UserError(f"{path} does not exist: the model wrote no scene spec S for "
                        f"{scene_id} (use --gt to start from the ground truth)")
    scene = load_run_scenes(run_dir, [scene_id]).get(scene_id)
    if scene is None or scene.spec is None:
        raise UserError(f"scene {scene_id} of {run_dir} has no ground-truth spec (only "
                        "generated benchmarks have one)")
    try:
        base = merged_spec(scene.spec, read_json(path))
    except (SpecTrackError, ValueError) as exc:
        raise UserError(f"{path}: the model's S cannot be simulated: {exc}") from None
    return scene, base, "the model's S"


def _simulate_and_render(scene, spec: dict, name: str, engine, contract, cache, out: Path):
    """Simulate ``spec``, replay it with the engine's reference program, keep its video; the
    rollout and the decoded frames."""
    from visphy_core.execute.pipeline import render_cached
    from visphy_core.spec.spec_track import SpecTrackError, simulate, simulated_scene

    try:
        rollout = simulate(spec)
    except SpecTrackError as exc:
        raise UserError(f"the {name} scene cannot be simulated: {exc}") from None
    program = engine.program_from_spec(simulated_scene(scene, spec, rollout=rollout))
    outcome = render_cached(engine, program, contract, cache)
    if outcome.failure is not None:
        raise UserError(f"the reference program of {engine.name} failed to render the {name} "
                        f"scene: {outcome.failure.value} {outcome.error or ''}".strip())
    (out / f"{name}.mp4").write_bytes(outcome.video_path.read_bytes())
    arrays = {"body_ids": np.array(rollout.body_ids, dtype=str),
              "frame_poses": rollout.frame_poses, "frame_steps": rollout.frame_steps,
              "frame_times_s": rollout.frame_times_s, "dt_s": float(spec["world"]["dt_s"])}
    for name_ in ("step_poses", "step_touching"):  # both simulators record them
        if getattr(rollout, name_, None) is not None:
            arrays[name_] = getattr(rollout, name_)
    np.savez_compressed(out / f"trajectory.{name}.npz", **arrays)
    return rollout, outcome.frames


def side_by_side(left: np.ndarray, right: np.ndarray, labels: tuple[str, str]) -> np.ndarray:
    """Frames ``left | right`` (N×H×2W×3), each half labelled in its top-left corner, a
    one-pixel grey rule on each side of the seam."""
    from PIL import Image, ImageDraw, ImageFont

    n, h, w, _ = left.shape
    frames = np.concatenate([left, right], axis=2)
    font = ImageFont.load_default(size=12)
    stamp = Image.new("RGB", (2 * w, LABEL_HEIGHT), (255, 255, 255))
    draw = ImageDraw.Draw(stamp)
    for i, text in enumerate(labels):
        while text and draw.textlength(text, font=font) > w - 10:
            text = text[:-2] + "…"
        width = int(draw.textlength(text, font=font)) + 8
        draw.rectangle([i * w, 0, i * w + width, LABEL_HEIGHT - 1], fill=(255, 255, 255),
                       outline=(120, 120, 120))
        draw.text((i * w + 4, 3), text, fill=(0, 0, 0), font=font)
    label = np.asarray(stamp)
    mask = np.any(label != 255, axis=2)
    for i in range(2):  # only the label boxes cover the scene
        x0 = i * w
        cols = np.nonzero(mask[:, x0:x0 + w].any(axis=0))[0]
        if len(cols):
            x1 = x0 + int(cols.max()) + 1
            frames[:, :LABEL_HEIGHT, x0:x1] = label[:, x0:x1]
    frames[:, :, w - 1:w + 1] = 128
    return frames


def _write_json(path: Path, obj) -> None:
    path.write_text(json.dumps(obj, indent=1, default=str) + "\n")
