"""``visphy render REPLY --engine E [--scene ID]``: one reply, end to end.

What a user does to debug one program: the reply file (a model's whole reply, or a bare
``.html``/``.py`` program) goes through exactly the pipeline a run uses (extraction, S
validation, the sandboxed render, scoring), played back by the model the root config's
``render.model`` names, with no model call, no tracking and no repair call. Only the named
scene is loaded (a generated dataset builds that one scene, not its split;
`visphy_core.execute.render_one`). Without ``--scene`` the program is rendered alone and nothing
is scored (`visphy_core.execute.render_program`). Everything lands in one folder: the program,
the render log, the video, the scores. The terminal gets a few lines: the video with its frames
and render time, the scores this scene has (every column is in ``scores.json`` /
``result.json``). Exit status 0 when the program rendered, 1 when it failed (the class and the
reason are printed), 2 for bad input.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from visphy_core.execute.render_program import DEFAULT_FPS, DEFAULT_FRAMES, DEFAULT_SIZE
from visphy_core.infra.errors import UserError


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


def render_command(argv: list[str]) -> int:
    """Parse ``argv``, check the reply file and the scene id, and render (and score)."""
    from visphy_core.execute.render_one import render_scene
    from visphy_core.execute.render_program import render_alone

    args = _parser().parse_intermixed_args(argv)  # overrides before or after the options
    reply = Path(args.reply).resolve()
    if not reply.is_file():
        raise UserError(f"reply file not found: {reply}")
    if args.scene is None:
        return render_alone(args, reply)
    if not args.scene or any(c in args.scene for c in ",[]* "):
        raise UserError(f"--scene {args.scene!r}: name exactly one scene id, e.g. "
                        "--scene task10001_000")
    return render_scene(args, reply)
