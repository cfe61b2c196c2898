"""``python -m visphy_core render REPLY --engine E --scene ID``: one reply, end to end.

What a user does to debug one program: the reply file (a model's whole reply, or a bare
``.html``/``.py`` program) goes through exactly the pipeline a run uses (extraction, S
validation, the sandboxed render, scoring), as the ``replay`` model, with no model call, no
tracking and no repair call. Everything lands in one folder: the program, the render log, the
video, the scores. Exit status 0 when the program rendered, 1 when it failed (the class and the
reason are printed), 2 for bad input.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import sys
from pathlib import Path

from visphy_core.infra.errors import UserError
from visphy_core.scoring.score import ScoringProtocol, select_metrics


def _parser() -> argparse.ArgumentParser:
    home = os.environ.get("VISPHY_HOME", "visphy-out")
    p = argparse.ArgumentParser(
        prog="python -m visphy_core render",
        description="Extract, render and score one reply file against one scene.")
    p.add_argument("reply", help="a reply file (analysis + fenced program) or a bare program")
    p.add_argument("--engine", required=True, help="threejs, p5, svg, manim, blender, ...")
    p.add_argument("--scene", required=True, help="scene id, e.g. vpb3-s0-2d-t001-v00")
    p.add_argument("--dataset", default="visphybench",
                   help="dataset config holding the scene (default: visphybench)")
    p.add_argument("--metrics", default=None, help="comma-separated metric names")
    p.add_argument("--judge", default=None,
                   help="judge config(s), e.g. gemini or gemini,gpt_frames")
    p.add_argument("-o", "--out", default=None,
                   help=f"output folder (default: {home}/render/<scene>_<engine>_<time>)")
    p.add_argument("overrides", nargs="*", help="more Hydra overrides, e.g. engine.timeout_s=20")
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
    if not args.scene or any(c in args.scene for c in ",[]* "):
        raise UserError(f"--scene {args.scene!r}: name exactly one scene id, e.g. "
                        "--scene task10001_000")
    overrides = [f"engine={args.engine}", f"dataset={args.dataset}",
                 f"dataset.scenes=[{args.scene}]", "model=replay",
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
    model = registry.get("models", "replay")(cfg.model)
    judges = [(str(k), registry.get("judges", str(n.name))(n))
              for k, n in (cfg.get("judge") or {}).items()]
    for judge in judges:
        judge[1].check_ready()
    cache = Cache(Path(cfg.paths.cache_dir).resolve(), enabled=bool(cfg.run.cache))
    scenes = load_dataset(cfg.dataset, Path(cfg.paths.data_dir).resolve(), progress=False)
    if len(scenes) != 1:
        raise UserError(f"--scene {args.scene} selects {len(scenes)} scenes of dataset "
                        f"{args.dataset}; name exactly one")
    (scene,) = scenes
    out = Path(args.out) if args.out else Path(cfg.paths.root) / "render" / (
        f"{scene.scene_id}_{args.engine}_{dt.datetime.now():%Y-%m-%d_%H-%M-%S}")
    out.mkdir(parents=True, exist_ok=True)
    ledger = UsageLedger(out / "calls.jsonl")
    engine = registry.get("engines", cfg.engine.name)(cfg.engine)
    services = SceneServices(
        model=model, caller=ModelCaller(model, cache, ledger), engine=engine,
        metrics=select_metrics(registry, cfg.metrics),
        protocol=ScoringProtocol.from_cfg(cfg.metrics),
        settings=PipelineSettings(prompt=PromptSettings.from_cfg(cfg.prompt), retry=False,
                                  fallback=False, timeout_s=cfg.engine.timeout_s,
                                  seed=cfg.run.seed),
        cache=cache, judges=JudgeCaller(judges, cache, ledger) if judges else None,
        references=ReferenceWriter(cfg.reference, cache))
    from visphy_core.execute.run import _isolation

    _isolation(cfg)
    try:
        result = process_scene(scene, services, out)
    finally:
        engine.close()
    (out / "result.json").write_text(json.dumps(result.row(), indent=1, default=str))
    _report(result, out)
    return 0 if result.model_success else 1


def _report(result, out: Path) -> None:
    ok = result.model_success
    print(f"{result.scene_id}: {'rendered' if ok else 'FAILED'}"
          + ("" if ok else f" ({result.failure_class}): {result.failure_detail}"))
    if result.render_wall_s is not None:
        print(f"render: {result.render_wall_s:.2f} s"
              + (" (cached)" if result.render_cached else "")
              + f", isolation {result.isolation or 'unknown'}")
    if result.spec_valid is not None:
        print("scene spec S: " + ("valid" if result.spec_valid else
                                  "invalid: " + "; ".join(result.spec_problems[:3])))
    if result.flags:
        print(f"flags: {', '.join(result.flags)}")
    for name, value in result.scores.items():
        shown = "—" if value is None else f"{value:.4f}"
        why = result.unavailable.get(name)
        print(f"  {name:>14} {shown}" + (f"  ({why})" if why else ""))
    files = sorted(p.name for p in out.iterdir() if p.is_file())
    print(f"folder: {out}  ({', '.join(files)})", file=sys.stdout)
