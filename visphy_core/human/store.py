"""The ratings file: ``<run_dir>/human_ratings.jsonl``, one JSON object per rating, appended.

Each line is exactly ``{"scene_id": str, "rater": str, "rating": int 1..5, "item": str,
"ts": iso8601, "comment": str|null}`` (keys in that order); the leaderboard's Human column and
its inter-rater agreement are computed from these files. A rating lives beside the run it
rates, so copying a run directory copies its ratings. Whether a rater already rated an item is
read from that run's file by (scene id, rater), so it survives moving the run directory.
"""

from __future__ import annotations

import datetime as dt
import json
import re
import threading
from pathlib import Path

from visphy_core.human.items import RatingItem
from visphy_core.infra import files
from visphy_core.infra.errors import UserError
from visphy_core.results.layout import RATINGS as RATINGS_FILE

RATINGS = range(1, 6)
MAX_COMMENT = 2000
RATER_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.@+-]{0,63}$")


def check_rater(rater: str) -> str:
    """The rater id, or `UserError`: 1–64 characters of letters, digits and ``_ . @ + -``."""
    if not RATER_PATTERN.match(rater or ""):
        raise UserError(f"--rater {rater!r}: use 1-64 letters, digits or _ . @ + - (e.g. "
                        "--rater alice), the same id every session")
    return rater


def rating_record(item: RatingItem, rater: str, rating: int, comment: str | None,
                  ts: dt.datetime | None = None) -> dict:
    """One line of the ratings file, keys in the file's order."""
    text = (comment or "").strip()[:MAX_COMMENT]
    when = (ts or dt.datetime.now(dt.timezone.utc)).isoformat(timespec="seconds")
    return {"scene_id": item.scene_id, "rater": rater, "rating": int(rating),
            "item": item.item, "ts": when, "comment": text or None}


def read_ratings(run_dir: Path) -> list[dict]:
    """The well-formed lines of a run's ratings file (a torn or foreign line is skipped)."""
    path = Path(run_dir) / RATINGS_FILE
    if not files.is_file(path, run_dir):
        return []
    out = []
    for line in files.read_text(path, run_dir, kind="jsonl").splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        rating = row.get("rating") if isinstance(row, dict) else None
        if isinstance(rating, int) and not isinstance(rating, bool) and rating in RATINGS \
                and isinstance(row.get("scene_id"), str) and isinstance(row.get("rater"), str):
            out.append(row)
    return out


class RatingStore:
    """Appends ratings to the run directories of ``items`` and knows which ones a rater gave."""

    def __init__(self, items: list[RatingItem]):
        self.items = {i.item: i for i in items}
        self._lock = threading.Lock()

    def rated_by(self, rater: str) -> set[str]:
        """Item ids ``rater`` has rated (in any earlier session)."""
        done: set[str] = set()
        by_run: dict[Path, dict[str, str]] = {}
        for item in self.items.values():
            by_run.setdefault(item.run_dir, {})[item.scene_id] = item.item
        for run_dir, scenes in by_run.items():
            for row in read_ratings(run_dir):
                if row["rater"] == rater and row["scene_id"] in scenes:
                    done.add(scenes[row["scene_id"]])
        return done

    def append(self, item: RatingItem, rater: str, rating: int, comment: str | None) -> dict:
        """Write one rating (a single ``write`` of a whole line, under a lock)."""
        record = rating_record(item, rater, rating, comment)
        line = (json.dumps(record, ensure_ascii=False) + "\n").encode("utf-8")
        with self._lock:  # never through a link, never into a file visphy did not create
            files.append_line(item.run_dir / RATINGS_FILE, line, item.run_dir, fsync=True)
        return record
