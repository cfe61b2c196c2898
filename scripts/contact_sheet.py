"""The README's contact sheet: key frames 1 and 10 (2D) / frames 1 and 38 (3D) of generated
scenes of the ``test`` split, labelled, in one PNG.

    .venv/bin/python scripts/contact_sheet.py [--data-dir visphy-out/data]
        [--out docs/img/contact_sheet.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--data-dir", default="visphy-out/data")
    parser.add_argument("--out", default="docs/img/contact_sheet.png")
    parser.add_argument("--n2d", type=int, default=8)
    parser.add_argument("--n3d", type=int, default=4)
    args = parser.parse_args()

    from visphy_core.infra.video import decode_video
    from visphy_plugins.datasets.visphybench.build import build_dataset
    from visphy_plugins.datasets.visphybench.loader import load_generated
    from visphy_plugins.datasets.visphybench.preview import write_contact_sheet

    root = build_dataset(Path(args.data_dir), split="test", progress=True)
    scenes = load_generated(root, split="test")
    picks = [s for s in scenes if s.dim == "2d"][:args.n2d] + \
        [s for s in scenes if s.dim == "3d"][:args.n3d]
    tiles = []
    for scene in picks:
        frames = decode_video(scene.video_path)[0]
        later = 9 if scene.dim == "2d" else len(frames) // 2
        short = scene.scene_id.split("-", 2)[-1]  # 2d-t001-v00
        tiles += [(f"{short} f1", frames[0]), (f"{short} f{later + 1}", frames[later])]
    path = write_contact_sheet(tiles, Path(args.out), columns=6, thumb=200)
    print(f"{path}: {len(picks)} scenes from {root}")


if __name__ == "__main__":
    main()
