"""One reply file rendered and scored against one scene, through exactly the pipeline a run
uses (`visphy_core.execute.pipeline.process_scene`): the command line is `visphy_core.cli.render`.

Only the named scene is loaded (a generated dataset builds that one scene, not its split); the
reply is played back by the model the root config's ``render.model`` names, with no model call,
no tracking and no repair call. Everything lands in one folder: the program, the render log,
the video, the scores (``result.json``); the terminal gets a few lines (`_report`).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from pathlib import Path

from visphy_core.infra.errors import UserError
from visphy_core.results import layout
from visphy_core.scoring.headline import Headline
from visphy_core.scoring.score import ScoringProtocol, select_metrics


def render_scene(args: argparse.Namespace, reply: Path) -> int:
    """Render and score ``reply`` (an existing file) against ``args.scene`` (one scene id) with
    the options of `visphy_core.cli.render`; 0 when the program rendered, else 1."""
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
    ledger = UsageLedger(out / layout.CALLS)
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
    (out / layout.RESULT).write_text(json.dumps(result.row(), indent=1, default=str))
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
        video = f"{out / layout.VIDEO} ({clip.n_frames} frames {clip.width}x{clip.height} @ " \
                f"{clip.fps:g} fps) · " if ok and (out / layout.VIDEO).is_file() else ""
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
