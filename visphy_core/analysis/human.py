"""Human 1–5 ratings (``<run_dir>/human_ratings.jsonl``, written by the rating page): read them,
resolve re-ratings, and summarise them per run and per scene.

One JSON object per line: ``{"scene_id", "rater", "rating" (int 1..5), "item", "ts", ...}``. A
rater may rate an item again: the last line wins. A line that is not such an object (a torn
write, a rating outside 1..5) is skipped and counted, never guessed at.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd

from visphy_core.analysis.agreement import krippendorff_alpha

log = logging.getLogger("visphy.analysis")
COLUMNS = ["scene_id", "rater", "rating", "item", "ts"]


def _valid(obj: object) -> bool:
    if not isinstance(obj, dict):
        return False
    rating = obj.get("rating")
    return (isinstance(obj.get("scene_id"), str) and isinstance(obj.get("rater"), str)
            and isinstance(rating, int) and not isinstance(rating, bool) and 1 <= rating <= 5)


def read_ratings(path: Path | None) -> pd.DataFrame:
    """The ratings in ``path`` (empty when there is none), one row per (rater, item): the last
    line wins. ``attrs["skipped"]`` counts the lines that were not valid ratings."""
    rows, skipped = [], 0
    if path is not None and Path(path).is_file():
        for line in Path(path).read_text(errors="replace").splitlines():
            if not line.strip():
                continue
            try:
                obj = json.loads(line)
            except ValueError:
                obj = None
            if not _valid(obj):
                skipped += 1
                continue
            rows.append({"scene_id": obj["scene_id"], "rater": obj["rater"],
                         "rating": int(obj["rating"]),
                         "item": str(obj.get("item") or obj["scene_id"]),
                         "ts": str(obj.get("ts") or "")})
    if skipped:
        log.warning("%s: %d line(s) that are not valid ratings skipped", path, skipped)
    df = pd.DataFrame(rows, columns=COLUMNS)
    if len(df):
        df = df.drop_duplicates(["rater", "item"], keep="last").reset_index(drop=True)
    df["rating"] = df["rating"].astype("int64")
    df.attrs["skipped"] = skipped
    return df


def scene_means(ratings: pd.DataFrame) -> pd.Series:
    """The mean rating of each scene (over raters and items), indexed by scene_id."""
    if ratings.empty:
        return pd.Series(dtype="float64", name="human")
    return ratings.groupby("scene_id")["rating"].mean().rename("human")


def alpha_of(ratings: pd.DataFrame, unit: list[str] | None = None) -> float:
    """Ordinal Krippendorff's alpha of raters over units (default: the item)."""
    if ratings.empty:
        return float("nan")
    unit = unit or ["item"]
    table = ratings.pivot_table(index="rater", columns=unit, values="rating", aggfunc="last")
    return krippendorff_alpha(table.to_numpy(dtype=np.float64), "ordinal")


def summarise_ratings(ratings: pd.DataFrame) -> dict:
    """``mean`` (over scenes of each scene's mean rating, so a scene many raters saw does not
    weigh more), ``n`` ratings, ``raters``, ``scenes`` and ordinal ``alpha``."""
    per_scene = scene_means(ratings)
    return {"mean": float(per_scene.mean()) if len(per_scene) else float("nan"),
            "n": int(len(ratings)), "raters": int(ratings["rater"].nunique()),
            "scenes": int(len(per_scene)), "alpha": alpha_of(ratings)}
