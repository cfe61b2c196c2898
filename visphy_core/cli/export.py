"""``visphy export RUN_DIR --format parquet|csv [-o OUT]``: a run's scores as one tidy table
(`visphy_core.results.tidy`); ``visphy export-dataset --format F -o DIR [overrides]``: a
dataset's scenes as a folder that Hugging Face ``datasets`` loads, written by the dataset plugin
``F`` that reads it back (``dataset=F dataset.root=DIR``; the formats are the installed dataset
plugins with an ``export``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from visphy_core.infra.errors import UserError

FORMATS = ("parquet", "csv")


def _run_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="visphy export",
        description="Write a run's scores as a tidy table: one row per (scene, score column) "
                    "with the column spelt out (kind, metric, pairing, track, normalised), the "
                    "scene's descriptors and the run's; a value a scene lacks is null with the "
                    "reason in `unavailable`. An unfinished run gives the rows it has.")
    parser.add_argument("run_dir", type=Path, metavar="RUN_DIR",
                        help="a run directory (<VISPHY_HOME>/runs/<run>)")
    parser.add_argument("--format", choices=FORMATS, default="parquet")
    parser.add_argument("-o", "--output", default=None,
                        help="the file to write (default: <run name>.scores.<format> in the "
                             "current directory; '-' writes CSV to standard output)")
    return parser


def cmd_export(argv: list[str]) -> int:
    from visphy_core.results.tidy import tidy_scores

    args = _run_parser().parse_args(argv)
    table = tidy_scores(args.run_dir)
    if args.output == "-":
        if args.format != "csv":
            raise UserError("export: -o - writes CSV only (add --format csv)")
        table.to_csv(sys.stdout, index=False)
        return 0
    out = Path(args.output or f"{Path(args.run_dir).resolve().name}.scores.{args.format}")
    if out.is_dir():
        raise UserError(f"export: {out} is a directory; name the file to write")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.partial")
    if args.format == "csv":
        table.to_csv(tmp, index=False)
    else:
        table.to_parquet(tmp, index=False)
    tmp.replace(out)
    scenes = table["scene_id"].nunique() if len(table) else 0
    print(f"{out}: {len(table)} rows ({scenes} scenes × {table['column'].nunique()} score "
          f"columns)")
    return 0


def dataset_formats() -> list[str]:
    """The installed dataset plugins that write a dataset folder (an ``export`` method)."""
    from visphy_core.api.registry import get_registry

    return sorted(name for name, (cls, _plugin) in get_registry().datasets.items()
                  if callable(getattr(cls, "export", None)))


def cmd_export_dataset(argv: list[str]) -> int:
    formats = dataset_formats()
    default = formats[0] if formats else None
    parser = argparse.ArgumentParser(
        prog="visphy export-dataset",
        description="Write a dataset's scenes (the dataset a run with the same overrides "
                    "would evaluate, built first when it is generated) as a Hugging Face "
                    "dataset folder: one Parquet file per split, the clips and trajectories "
                    f"beside it, a dataset card. `dataset={default or 'FORMAT'} "
                    "dataset.root=DIR` runs on it.")
    parser.add_argument("--format", default=default, choices=formats,
                        help="the dataset plugin that writes the folder and reads it back: "
                             f"{', '.join(formats) or 'none installed'} (default: {default})")
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="DIR",
                        help="the folder to write (created; an existing split is replaced)")
    parser.add_argument("--split", action="append", default=None, metavar="SPLIT",
                        help="a split to export (repeat for several; default: the dataset "
                             "config's split, e.g. mini)")
    parser.add_argument("overrides", nargs="*", default=[],
                        help="a run's dataset overrides: dataset=visphybench_test, "
                             "dataset.limit=N, 'dataset.scenes=[...]', paths.data_dir=...")
    args = parser.parse_args(argv)
    from visphy_core.config.check import compose
    from visphy_core.execute.datasets import get_dataset, load_dataset

    if args.format is None:
        raise UserError("export-dataset: no installed dataset plugin writes a dataset folder")
    writer = getattr(get_dataset(args.format), "export", None)
    if writer is None:
        raise UserError(f"export-dataset: the dataset plugin {args.format!r} cannot write")
    splits = args.split or [None]
    for split in splits:
        overrides = list(args.overrides) + ([f"dataset.split={split}"] if split else [])
        cfg = compose(overrides)
        scenes = load_dataset(cfg.dataset, Path(str(cfg.paths.data_dir)), progress=False)
        name = str(cfg.dataset.split or cfg.dataset.name)
        writer(scenes, args.output, split=name)
        print(f"{name}: {len(scenes)} scenes")
    print(f"Hugging Face dataset ready in {args.output} "
          f"(datasets.load_dataset({str(args.output)!r}); "
          f"visphy dataset={args.format} dataset.root={args.output})")
    return 0
