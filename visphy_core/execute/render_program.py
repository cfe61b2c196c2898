"""``visphy render REPLY --engine E`` with no ``--scene``: render the program alone, score nothing.

What debugging one program needs when there is no scene to compare it with: no dataset is
loaded or built, no model, no metric. The reply (a model's whole reply, or a bare ``.html`` /
``.py`` program) is extracted and validated by the engine and rendered in the sandbox at the
clip shape given by ``--fps``, ``--frames`` and ``--size`` (default: the paper's 2D clip, 17
frames of 512×512 at 5 fps), through the render cache. The folder gets the program, the
render log, ``video.mp4`` and ``result.json``; the terminal gets a few lines: the video, its
frames and the render's time (or the failure class and its reason). Exit status 0 when it
rendered, 1 when it did not, 2 for bad input.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from visphy_core.api.engine import ProgramRejected, RenderContract, classify_frames
from visphy_core.api.extract import fenced_blocks
from visphy_core.infra.errors import UserError
from visphy_core.results import layout

#: the paper's 2D clip shape: 5 fps, 17 frames, 512×512
DEFAULT_FPS, DEFAULT_FRAMES, DEFAULT_SIZE = 5.0, 17, "512x512"
FENCE_FOR = {".html": "html", ".py": "python"}
MAX_REPLY = 4 << 20


def parse_size(text: str) -> tuple[int, int]:
    """``WxH`` (e.g. ``512x512``) as (width, height); `UserError` otherwise."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise UserError(f"--size {text!r}: write WIDTHxHEIGHT, e.g. --size 512x512") from None
    if not (8 <= width <= 4096 and 8 <= height <= 4096):
        raise UserError(f"--size {text}: each side must be 8 to 4096 pixels")
    return width, height


def reply_text(path: Path) -> str:
    """The reply; a bare ``.html`` / ``.py`` program is wrapped in its fence."""
    if path.stat().st_size > MAX_REPLY:
        raise UserError(f"{path}: a reply of {path.stat().st_size} bytes is too large")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise UserError(f"{path}: the reply is not UTF-8 text") from None
    blocks, unclosed = fenced_blocks(text)
    if not blocks and unclosed is None and path.suffix.lower() in FENCE_FOR:
        return f"```{FENCE_FOR[path.suffix.lower()]}\n{text.rstrip()}\n```\n"
    return text


def render_alone(args, reply: Path) -> int:
    """Extract, validate and render ``reply`` with ``args.engine``; see the module docstring."""
    from visphy_core.api.registry import get_registry
    from visphy_core.config.check import check_overrides
    from visphy_core.execute.pipeline import render_with_infra_retry
    from visphy_core.execute.run_setup import _isolation
    from visphy_core.infra.cache import Cache
    from visphy_core.results.row import SceneResult
    from visphy_core.results.write import write_artifact as _write

    if args.frames < 1:
        raise UserError(f"--frames {args.frames}: at least 1")
    if not args.fps > 0:
        raise UserError(f"--fps {args.fps:g}: must be above 0")
    width, height = parse_size(args.size)
    (cfg,) = check_overrides([f"engine={args.engine}", "tracking=none",
                              *args.overrides])[:1]
    text = reply_text(reply)
    contract = RenderContract(fps=float(args.fps), n_frames=int(args.frames), width=width,
                              height=height, dim=args.dim, timeout_s=cfg.engine.timeout_s,
                              seed=int(cfg.run.seed))
    out = Path(args.out) if args.out else Path(cfg.paths.root) / "render" / (
        f"{reply.stem}_{args.engine}_{dt.datetime.now():%Y-%m-%d_%H-%M-%S}")
    out.mkdir(parents=True, exist_ok=True)
    engine = get_registry().get("engines", cfg.engine.name)(cfg.engine)
    result = SceneResult(scene_id=reply.stem, dim=args.dim, difficulty=None, attempts=1)
    _isolation(cfg)
    try:
        program = engine.extract(text)
        engine.validate(program)
    except ProgramRejected as exc:
        result.failure_class, result.failure_detail = exc.failure.value, str(exc)
        outcome = None
    else:
        ext = "html" if program.language == "html" else "py"
        _write(out / layout.attempt_file(layout.PROGRAM, 1, ext), program.source)
        cache = Cache(Path(cfg.paths.cache_dir).resolve(), enabled=bool(cfg.run.cache))
        try:
            outcome = render_with_infra_retry(engine, program, contract, cache, out, 1,
                                              result)
        finally:
            engine.close()
        if outcome.failure is not None:
            result.failure_class = outcome.failure.value
            result.failure_detail = outcome.error or ""
            outcome = None
    if outcome is not None:
        result.model_success = result.system_success = True
        result.frame_digests = outcome.frame_digests
        _write(out / layout.VIDEO, outcome.video_path.read_bytes())
        flag = classify_frames(outcome.frames)
        if flag is not None and flag.value not in result.flags:
            result.flags.append(flag.value)
    (out / layout.RESULT).write_text(json.dumps(result.row(), indent=1, default=str))
    _say(result, out, contract)
    return 0 if result.model_success else 1


def _say(result, out: Path, contract: RenderContract) -> None:
    if not result.model_success:
        print(f"{result.scene_id}: FAILED ({result.failure_class}): {result.failure_detail}")
    else:
        print(f"{result.scene_id}: rendered {out / layout.VIDEO}")
        print(f"{contract.n_frames} frames {contract.width}x{contract.height} @ "
              f"{contract.fps:g} fps · render {result.render_wall_s:.2f} s"
              + (" (cached)" if result.render_cached else "")
              + f" · isolation {result.isolation or 'unknown'}")
    if result.flags:
        print(f"flags: {', '.join(result.flags)}")
    print("not scored: no --scene named (--scene ID renders at that scene's clip shape and "
          "scores against it)")
    print(f"folder: {out}")
