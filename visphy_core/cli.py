"""Command line: ``python -m visphy_core [subcommand | hydra overrides]``.

Subcommands:
  plugins        list installed plugins and what each registers (also: --plugins)
  setup          install the vendored JavaScript libraries (npm ci into the asset cache)
  build-dataset  generate VisPhyBench: build-dataset [--split S] [--seed N] [--data-dir DIR]
  normalise      resample a foreign video to a reference clip: normalise IN --like REF -o OUT
Anything else is a Hydra run: ``python -m visphy_core engine=threejs model=oracle dataset=mini``.
"""

from __future__ import annotations

import argparse
import sys

from visphy_core.config_check import ConfigError, check_overrides


def cmd_plugins(argv: list[str]) -> int:
    from rich.console import Console
    from rich.table import Table

    from visphy_core.plugins import describe_plugins

    table = Table(title="visphy plugins")
    for col in ("plugin", "distribution", "registers", "hooks"):
        table.add_column(col)
    for info in describe_plugins():
        regs = "; ".join(f"{kind}: {', '.join(sorted(names))}"
                         for kind, names in sorted(info.registers.items()))
        table.add_row(info.name, f"{info.distribution} {info.version}", regs or "—",
                      ", ".join(h.removeprefix("visphy_") for h in info.hooks))
    Console(width=160).print(table)
    return 0


def cmd_setup(argv: list[str]) -> int:
    from visphy_plugins.engines.js_assets import install_assets

    path = install_assets()
    print(f"browser engine libraries ready in {path}")
    return 0


def cmd_build_dataset(argv: list[str]) -> int:
    import os
    import time
    from pathlib import Path

    from visphy_core.bench.build import build_dataset

    home = os.environ.get("VISPHY_HOME", "visphy-out")
    parser = argparse.ArgumentParser(
        prog="python -m visphy_core build-dataset",
        description="Generate VisPhyBench (simulate every scene, render the requested split).")
    parser.add_argument("--split", default=None, help="sub, test or mini (default: all scenes)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data-dir", default=f"{home}/data")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    args = parser.parse_args(argv)
    start = time.perf_counter()
    root = build_dataset(Path(args.data_dir), seed=args.seed, split=args.split,
                         workers=args.workers)
    print(f"VisPhyBench (seed {args.seed}, split {args.split or 'all'}) ready in {root} "
          f"({time.perf_counter() - start:.1f} s)")
    return 0


def cmd_normalise(argv: list[str]) -> int:
    from pathlib import Path

    from visphy_core.video import decode_video, encode_video, normalise_clip

    parser = argparse.ArgumentParser(
        prog="python -m visphy_core normalise",
        description="Resample any video to a reference clip's fps, frame count and size "
                    "(nearest frame in time; aspect kept, padded with white).")
    parser.add_argument("video", help="the foreign video (a baseline's or upstream output)")
    parser.add_argument("--like", required=True, help="the reference clip to match")
    parser.add_argument("-o", "--output", required=True)
    args = parser.parse_args(argv)
    frames, info = decode_video(Path(args.video))
    _, target = decode_video(Path(args.like))
    out = normalise_clip(frames, info.fps, target)
    encode_video(out, Path(args.output), target.fps)
    print(f"{args.video}: {info.n_frames} frames {info.width}x{info.height} @ {info.fps:g} fps "
          f"-> {args.output}: {target.n_frames} frames {target.width}x{target.height} "
          f"@ {target.fps:g} fps")
    return 0


SUBCOMMANDS = {"plugins": cmd_plugins, "setup": cmd_setup, "build-dataset": cmd_build_dataset,
               "normalise": cmd_normalise}


def run_hydra(argv: list[str]) -> int:
    import hydra
    from hydra.core.global_hydra import GlobalHydra

    from visphy_core.plugins import get_registry

    get_registry()  # plugins store their structured configs before Hydra composes
    if not any(a in ("--help", "-h", "--hydra-help", "--info", "--cfg", "-c") or
               a.startswith("--info") for a in argv):
        try:
            check_overrides([a for a in argv if not a.startswith("-")])
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    GlobalHydra.instance().clear()

    @hydra.main(version_base="1.3", config_path="pkg://visphy_conf", config_name="config")
    def _main(cfg) -> None:
        from visphy_core.run import run_experiment

        run_experiment(cfg)

    sys.argv = [sys.argv[0]] + argv
    _main()
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in SUBCOMMANDS:
        return SUBCOMMANDS[argv[0]](argv[1:])
    if "--plugins" in argv:
        return cmd_plugins([])
    return run_hydra(argv)
