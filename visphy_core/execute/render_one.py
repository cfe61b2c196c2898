"""``visphy render REPLY --engine E [--scene ID]``: one reply, end to end.

What a user does to debug one program: the reply file (a model's whole reply, or a bare
``.html``/``.py`` program) goes through exactly the pipeline a run uses (extraction, S
validation, the sandboxed render, scoring), played back by the model the root config's
``render.model`` names, with no model call, no tracking and no repair call. Only the named
scene is loaded (a generated dataset builds that one scene, not its split). Without ``--scene``
the program is rendered alone and nothing is scored (`visphy_core.execute.render_program`).
Everything lands in one folder: the program, the render log, the video, the scores. The
terminal gets a few lines: the video with its frames and render time, the scores this scene has
(every column is in ``scores.json`` / ``result.json``). Exit status 0 when the program rendered,
1 when it failed (the class and the reason are printed), 2 for bad input.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import sys
from pathlib import Path

from visphy_core.execute.render_program import (
    DEFAULT_FPS,
    DEFAULT_FRAMES,
    DEFAULT_SIZE,
    render_alone,
)
from visphy_core.infra.errors import UserError
from visphy_core.results.layout import CALLS
from visphy_core.scoring.headline import Headline
from visphy_core.scoring.score import ScoringProtocol, select_metrics


def render_defaults() -> dict[str, str]:
    """The root config's ``render`` node (conf/config.yaml): the default dataset config and the
    model that plays a reply back."""
    from visphy_core.config.tree import root_node

    return {k: str(v) for k, v in (root_node().get("render") or {}).items()}


def _installed(kind: str) -> str:
    from visphy_core.api.registry import get_registry

    return ", ".join(sorted(getattr(get_registry(), kind)))


def _parser() -> argparse.ArgumentParser:
    home = os.environ.get("VISPHY_HOME", "visphy-out")
    defaults = render_defaults()
    p = argparse.ArgumentParser(
        prog="visphy render",
        description="Extract, render and score one reply file against one scene (only that "
                    "scene is loaded or built); without --scene, render the program alone "
                    "and score nothing.")
    p.add_argument("reply", help="a reply file (analysis + fenced program) or a bare program")
    p.add_argument("--engine", required=True,
                   help=f"the engine config: {_installed('engines')}")
    p.add_argument("--scene", default=None,
                   help="scene id, e.g. vpb3-s0-2d-t001-v00 (omitted: render only, no score)")
    p.add_argument("--dataset", default=defaults["dataset"],
                   help=f"dataset config holding the scene (default: {defaults['dataset']}, "
                        "render.dataset in conf/config.yaml)")
    p.add_argument("--metrics", default=None, help="comma-separated metric names")
    p.add_argument("--judge", default=None,
                   help=f"judge config(s), comma-separated; installed judges: "
                        f"{_installed('judges')}")
    p.add_argument("-o", "--out", default=None,
                   help=f"output folder (default: {home}/render/<scene>_<engine>_<time>)")
    p.add_argument("--fps", type=float, default=DEFAULT_FPS,
                   help=f"without --scene: frames per second (default {DEFAULT_FPS:g})")
    p.add_argument("--frames", type=int, default=DEFAULT_FRAMES,
                   help=f"without --scene: frames to capture (default {DEFAULT_FRAMES})")
    p.add_argument("--size", default=DEFAULT_SIZE,
                   help=f"without --scene: WIDTHxHEIGHT (default {DEFAULT_SIZE})")
    p.add_argument("--dim", choices=("2d", "3d"), default="2d",
                   help="without --scene: a 2D or 3D program (default 2d)")
    p.set_defaults(player=defaults["model"])  # render.model: plays the reply back
    p.add_argument("overrides", nargs="*", default=[],
                   help="more Hydra overrides, e.g. engine.timeout_s=20")
    return p


def render_reply(argv: list[str]) -> int:
    from visphy_core.api.registry import get_registry
    from visphy_core.calls.generation import ModelCaller
    from visphy_core.calls.judging import JudgeCaller
    from visphy_core.calls.prompts.build import PromptSettings
    from visphy_core.calls.references import ReferenceWriter
    from visphy_core.calls.usage import UsageLedger
    from visphy_core.config.check import check_overrides
    from visphy_core.execute.datasets import load_dataset
    from visphy_core.execute.pipeline import PipelineSettings, SceneServices, process_scene
    from visphy_core.infra.cache import Cache

    args = _parser().parse_intermixed_args(argv)  # overrides before or after the options
    reply = Path(args.reply).resolve()
    if not reply.is_file():
        raise UserError(f"reply file not found: {reply}")
    if args.scene is None:
        return render_alone(args, reply)
    if not args.scene or any(c in args.scene for c in ",[]* "):
        raise UserError(f"--scene {args.scene!r}: name exactly one scene id, e.g. "
                        "--scene task10001_000")
    overrides = [f"engine={args.engine}", f"dataset={args.dataset}",
                 f"dataset.scenes=[{args.scene}]", f"model={args.player}",
                 f"model.source={json.dumps(str(reply))}", "tracking=none", "run.retry=false"]
    if reply.suffix.lower() in (".mp4", ".webm", ".mov", ".mkv", ".avi"):
        overrides.append("model.output=video")  # a pixel-space model's video
    if args.metrics:
        overrides.append(f"metrics.names=[{args.metrics}]")
    if args.judge:
        overrides.append(f"judge=[{args.judge}]")
    overrides += args.overrides
    (cfg,) = check_overrides(overrides, inputs=True)[:1]
    registry = get_registry()
    model = registry.get("models", str(cfg.model.name))(cfg.model)
    judges = [(str(k), registry.get("judges", str(n.name))(n))
              for k, n in (cfg.get("judge") or {}).items()]
    for judge in judges:
        judge[1].check_ready()
    cache = Cache(Path(cfg.paths.cache_dir).resolve(), enabled=bool(cfg.run.cache))
    # a generated dataset renders only this scene (and writes its catalogue, the first time):
    # a terminal sees that progress, transient
    scenes = load_dataset(cfg.dataset, Path(cfg.paths.data_dir).resolve(),
                          progress=sys.stdout.isatty())
    if len(scenes) != 1:
        raise UserError(f"--scene {args.scene} selects {len(scenes)} scenes of dataset "
                        f"{args.dataset}; name exactly one")
    (scene,) = scenes
    out = Path(args.out) if args.out else Path(cfg.paths.root) / "render" / (
        f"{scene.scene_id}_{args.engine}_{dt.datetime.now():%Y-%m-%d_%H-%M-%S}")
    out.mkdir(parents=True, exist_ok=True)
    ledger = UsageLedger(out / CALLS)
    engine = registry.get("engines", cfg.engine.name)(cfg.engine)
    metrics = select_metrics(registry, cfg.metrics)
    services = SceneServices(
        model=model, caller=ModelCaller(model, cache, ledger), engine=engine,
        metrics=metrics, protocol=ScoringProtocol.from_cfg(cfg.metrics),
        headline=Headline.for_run(cfg.metrics, metrics),
        settings=PipelineSettings(prompt=PromptSettings.from_cfg(cfg.prompt), retry=False,
                                  fallback=False, timeout_s=cfg.engine.timeout_s,
                                  seed=cfg.run.seed),
        cache=cache, judges=JudgeCaller(judges, cache, ledger) if judges else None,
        references=ReferenceWriter(cfg.reference, cache))
    from visphy_core.execute.run_setup import _isolation

    _isolation(cfg)
    try:
        result = process_scene(scene, services, out)
    finally:
        engine.close()
    (out / "result.json").write_text(json.dumps(result.row(), indent=1, default=str))
    _report(result, out, scene, services.headline)
    return 0 if result.model_success else 1


def _report(result, out: Path, scene, headline: Headline | None = None) -> None:
    """A few lines: the outcome, the video (frames, render time), the scores this scene has in
    the primary view; how many more columns ``scores.json`` holds and how many are empty."""
    ok = result.model_success
    print(f"{result.scene_id}: {'rendered' if ok else 'FAILED'}"
          + ("" if ok else f" ({result.failure_class}): {result.failure_detail}"))
    if result.render_wall_s is not None:
        clip = scene.clip
        video = f"{out / 'video.mp4'} ({clip.n_frames} frames {clip.width}x{clip.height} @ " \
                f"{clip.fps:g} fps) · " if ok and (out / "video.mp4").is_file() else ""
        print(f"video: {video}render {result.render_wall_s:.2f} s"
              + (" (cached)" if result.render_cached else "")
              + f" · isolation {result.isolation or 'unknown'}")
    if result.spec_valid is not None:
        print("scene spec S: " + ("valid" if result.spec_valid else
                                  "invalid: " + "; ".join(result.spec_problems[:3])))
    if result.flags:
        print(f"flags: {', '.join(result.flags)}")
    head = headline.name if headline is not None and headline.name in result.scores else None
    if head is not None:
        value = result.scores[head]
        print(f"{head}: " + (f"{value:.3f} (0 = the first key frame held, 1 = the ground "
                                  "truth's twin; details in headline.json)" if value is not None
                                  else "undefined on this scene (headline.json says why)"))
    shown = {n: v for n, v in result.scores.items()
             if v is not None and "." not in n and n != head}
    width = max((len(n) for n in shown), default=0)
    for name, value in shown.items():
        print(f"  {name:>{width}} {value:.4f}")
    more = sum(1 for n, v in result.scores.items() if v is not None and n not in shown)
    empty = [n for n, v in result.scores.items() if v is None]
    if more or empty:
        why = sorted({w.split(":")[0] for n, w in result.unavailable.items() if n in empty})
        print(f"scores.json: {len(shown) + more} score(s)"
              + (f", {more} of them in other views (aligned, paper, spec, norm)" if more else "")
              + (f"; {len(empty)} empty" + (f" ({'; '.join(why[:3])}"
                                              + (", …" if len(why) > 3 else "") + ")"
                                              if why else "") if empty else ""))
    print(f"folder: {out}")
