"""Regenerate the catalogue shipped with visphy
(``plugins/datasets/visphybench/data/catalogue-v<version>-seed<seed>.json.gz`` and its line in
``data/catalogues.json``): simulate the whole catalogue of the current generator and write it.

    .venv/bin/python scripts/ship_catalogue.py                    # simulate seed 0 and ship it
    .venv/bin/python scripts/ship_catalogue.py --check            # exit 1 when the shipped file
                                                                  # is not what a build gives
    .venv/bin/python scripts/ship_catalogue.py --from ROOT/catalogue.json   # ship a catalogue
                                                                  # simulated already

Run it after any change that alters a scene (templates, filters, features, labels, splits, the
simulators); bump ``GENERATOR_VERSION`` as well when the change alters scenes users already have.
``tests/test_shipped_catalogue.py`` compares the shipped file with a fresh simulation.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--check", action="store_true",
                        help="compare the shipped catalogue with a simulation; write nothing")
    parser.add_argument("--from", dest="source", default=None,
                        help="a catalogue.json simulated by this generator (build-dataset "
                             "--rebuild-catalogue) to ship instead of simulating one")
    args = parser.parse_args(argv)

    from visphy_plugins.datasets.visphybench.build import (
        BUILDER_VERSION,
        _parse_catalogue,
        catalogue_bytes,
    )
    from visphy_plugins.datasets.visphybench.catalogue import build_catalogue
    from visphy_plugins.datasets.visphybench.shipped import (
        DATA,
        ShippedDamaged,
        shipped_bytes,
        shipped_name,
        write_shipped,
    )

    start = time.perf_counter()
    if args.source:
        raw = Path(args.source).read_bytes()
        catalogue = _parse_catalogue(json.loads(raw), args.seed)
        if isinstance(catalogue, str):
            print(f"{args.source}: not a {BUILDER_VERSION} catalogue of seed {args.seed} "
                  f"({catalogue})", file=sys.stderr)
            return 1
        if catalogue_bytes(catalogue) != raw:
            print(f"{args.source}: not as a build writes it", file=sys.stderr)
            return 1
    else:
        catalogue = build_catalogue(seed=args.seed, workers=args.workers, progress=True)
        raw = catalogue_bytes(catalogue)
    took = time.perf_counter() - start
    if args.check:
        try:
            shipped = shipped_bytes(args.seed)
        except ShippedDamaged as exc:
            print(f"the shipped catalogue is damaged: {exc}", file=sys.stderr)
            return 1
        if shipped != raw:
            print(f"{DATA / shipped_name(args.seed)} differs from the simulation "
                  f"({took:.0f} s): run scripts/ship_catalogue.py", file=sys.stderr)
            return 1
        print(f"{DATA / shipped_name(args.seed)} is what the generator simulates ({took:.0f} s)")
        return 0
    path = write_shipped(raw, args.seed, BUILDER_VERSION, len(catalogue.entries))
    print(f"shipped {path} ({len(catalogue.entries)} scenes, {len(raw)} bytes, "
          f"{path.stat().st_size} gzipped; {took:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
