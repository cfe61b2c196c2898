"""The datasheet of a built benchmark: what it contains, next to what the paper reports.

`write_datasheet` writes ``<root>/DATASHEET.md`` (for people) and ``<root>/datasheet.json`` (the
same numbers for programs). Both are deterministic: no timestamps, fixed orderings; the only
value that may differ between two builds of the same benchmark is the build time, and only when
one is given.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

from visphy_core.api.storage import atomic_write

#: VisPhyBench as published: scene and template counts.
PAPER_SCENES, PAPER_TEMPLATES = 209, 108
#: Object categories as published: (percentage of scenes containing the category, object count).
PAPER_CATEGORIES: dict[str, tuple[float, int]] = {
    "circle": (100.0, 779), "line": (83.2, 344), "rectangle": (62.8, 321),
    "u_shape": (24.6, 47), "triangle": (6.3, 16), "composite_shape": (7.3, 16),
}
#: Difficulty labels per split as published.
PAPER_DIFFICULTY: dict[str, dict[str, int]] = {
    "sub": {"easy": 114, "medium": 67, "hard": 28},
    "test": {"easy": 29, "medium": 17, "hard": 3},
}
LABELS = ("easy", "medium", "hard")
#: The published clips as measured (nine scenes the authors published with their code, decoded
#: frame by frame; docs/benchmark.md): min, median, max.
PUBLISHED_RED_RADIUS_PX = (17.0, 39.0, 56.0)      # 2D red ball
PUBLISHED_NONWHITE_PCT = (3.3, 4.4, 6.6)          # 2D non-white area per frame
PUBLISHED_OBJECTS_PER_SCENE = 1523 / 209          # the paper's category counts over 209 scenes
#: How a detected box is classified as a line or a rectangle.
LINE_RULE = "a box is a line when length/thickness ≥ 4, else a rectangle"
REQUIRED_KEYS = ("scene_id", "template_id", "dim", "family", "splits", "difficulty",
                 "categories", "n_objects_by_category")
DATASHEET_MD, DATASHEET_JSON = "DATASHEET.md", "datasheet.json"


def _check(entries: list[dict]) -> None:
    seen: set[str] = set()
    for i, entry in enumerate(entries):
        missing = [k for k in REQUIRED_KEYS if k not in entry]
        name = entry.get("scene_id", f"#{i}")
        if missing:
            raise ValueError(f"datasheet entry {name}: missing key(s) {', '.join(missing)}")
        if entry["scene_id"] in seen:
            raise ValueError(f"datasheet entry {name}: scene listed twice")
        seen.add(entry["scene_id"])
        if entry["dim"] not in ("2d", "3d"):
            raise ValueError(f"datasheet entry {name}: dim {entry['dim']!r} is not 2d or 3d")


def _split_order(names: set[str]) -> list[str]:
    known = [s for s in PAPER_DIFFICULTY if s in names]
    return known + sorted(names - set(known))


def datasheet_stats(entries: list[dict], rejected: dict[str, int],
                    build_seconds: float | None = None) -> dict[str, Any]:
    """The datasheet's numbers (what ``datasheet.json`` holds)."""
    _check(entries)
    n = len(entries)
    by_dim = Counter(e["dim"] for e in entries)
    templates = {(e["dim"], str(e["template_id"])) for e in entries}
    tmpl_by_dim = Counter(dim for dim, _ in templates)

    present: Counter[str] = Counter()
    objects: Counter[str] = Counter()
    for e in entries:
        counts = {c: int(k) for c, k in e["n_objects_by_category"].items()}
        present.update(set(e["categories"]) | {c for c, k in counts.items() if k > 0})
        objects.update(counts)
    cats = list(PAPER_CATEGORIES) + sorted((set(present) | set(objects)) - set(PAPER_CATEGORIES))
    categories = {}
    for c in cats:
        paper = PAPER_CATEGORIES.get(c)
        categories[c] = {
            "scenes": present[c], "share_pct": round(100.0 * present[c] / n, 1) if n else 0.0,
            "objects": objects[c],
            "paper_share_pct": paper[0] if paper else None,
            "paper_objects": paper[1] if paper else None,
        }

    split_names = {s for e in entries for s in e["splits"]}
    difficulty = {}
    for split in _split_order(split_names):
        labels = Counter(e["difficulty"] if e["difficulty"] in LABELS else "unlabelled"
                         for e in entries if split in e["splits"])
        row = {lab: labels[lab] for lab in LABELS}
        if labels["unlabelled"]:
            row["unlabelled"] = labels["unlabelled"]
        row["total"] = sum(labels.values())
        difficulty[split] = {"counts": row, "paper": PAPER_DIFFICULTY.get(split)}

    fam_scenes = Counter(e["family"] for e in entries)
    families = {}
    for fam in sorted(fam_scenes):
        members = [e for e in entries if e["family"] == fam]
        families[fam] = {
            "scenes": fam_scenes[fam],
            "templates": len({(e["dim"], str(e["template_id"])) for e in members}),
            "dims": sorted({e["dim"] for e in members}),
        }

    look = _look(entries)
    rejected_sorted = {reason: int(rejected[reason]) for reason in sorted(rejected)}
    return {
        "scenes": {"total": n, "2d": by_dim["2d"], "3d": by_dim["3d"], "paper": PAPER_SCENES},
        "templates": {"total": len(templates), "2d": tmpl_by_dim["2d"], "3d": tmpl_by_dim["3d"],
                      "paper": PAPER_TEMPLATES},
        "categories": categories,
        "look": look,
        "difficulty": difficulty,
        "families": families,
        "rejected": {"by_reason": rejected_sorted, "total": sum(rejected_sorted.values())},
        "line_rectangle_rule": LINE_RULE,
        "build_seconds": None if build_seconds is None else round(float(build_seconds), 1),
    }


def _spread(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    v = sorted(values)
    mid = v[len(v) // 2] if len(v) % 2 else (v[len(v) // 2 - 1] + v[len(v) // 2]) / 2
    return {"min": round(v[0], 2), "median": round(mid, 2), "max": round(v[-1], 2)}


def _look(entries: list[dict]) -> dict[str, Any]:
    """Sizes, covered area and object counts against the published clips (scenes written
    before ``look`` was recorded are left out of these rows)."""
    two_d = [e["look"] for e in entries if e["dim"] == "2d" and e.get("look")]
    radii = [lk["red_ball_radius_px"] for lk in two_d if lk.get("red_ball_radius_px")]
    nonwhite = [100.0 * lk["nonwhite_frac"]["median"] for lk in two_d]
    counts = {dim: [sum(int(k) for k in e["n_objects_by_category"].values())
                    for e in entries if e["dim"] == dim] for dim in ("2d", "3d")}
    every = counts["2d"] + counts["3d"]
    return {
        "red_ball_radius_px_2d": {"generated": _spread(radii),
                                  "published": dict(zip(("min", "median", "max"),
                                                        PUBLISHED_RED_RADIUS_PX))},
        "nonwhite_pct_2d": {"generated": _spread(nonwhite),
                            "published": dict(zip(("min", "median", "max"),
                                                  PUBLISHED_NONWHITE_PCT))},
        "objects_per_scene": {
            "generated": round(sum(every) / len(every), 2) if every else None,
            "generated_2d": round(sum(counts["2d"]) / len(counts["2d"]), 2) if counts["2d"]
            else None,
            "generated_3d": round(sum(counts["3d"]) / len(counts["3d"]), 2) if counts["3d"]
            else None,
            "published": round(PUBLISHED_OBJECTS_PER_SCENE, 2)},
    }


def _within(generated: dict | None, published: dict) -> str:
    if generated is None:
        return "–"
    ok = (published["min"] <= generated["median"] <= published["max"]
          and generated["min"] >= published["min"] * 0.8
          and generated["max"] <= published["max"] * 1.2)
    return "yes" if ok else "no"


def _paper(value: Any) -> str:
    return "–" if value is None else str(value)


def render_markdown(stats: dict[str, Any]) -> str:
    """DATASHEET.md from `datasheet_stats`."""
    s, t = stats["scenes"], stats["templates"]
    out = [
        "# VisPhyBench datasheet",
        "",
        "Numbers computed from the built scenes; the *paper* columns are VisPhyBench as published.",
        "",
        "## Scenes and templates",
        "",
        "| | total | 2D | 3D | paper |",
        "|---|---:|---:|---:|---:|",
        f"| scenes | {s['total']} | {s['2d']} | {s['3d']} | {s['paper']} |",
        f"| templates | {t['total']} | {t['2d']} | {t['3d']} | {t['paper']} |",
        "",
        "## Object categories",
        "",
        "Share = fraction of scenes with at least one object of the category; "
        "objects = total count.",
        "",
        "| category | scenes | share | objects | paper share | paper objects |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for cat, row in stats["categories"].items():
        paper_share = "–" if row["paper_share_pct"] is None else f"{row['paper_share_pct']:.1f}%"
        out.append(f"| {cat} | {row['scenes']} | {row['share_pct']:.1f}% | {row['objects']} | "
                   f"{paper_share} | {_paper(row['paper_objects'])} |")
    look = stats.get("look") or {}
    if look:
        out += ["", "## What the clips look like, against the published clips", "",
                "Published: the nine clips the authors released with their code, measured frame "
                "by frame (min–median–max); objects per scene from the paper's category "
                "counts (1,523 over 209 scenes).", "",
                "| measure | generated | published | in range (median; ends ±20 %) |",
                "|---|---|---|---|"]
        for key, name in (("red_ball_radius_px_2d", "2D red-ball radius (px, frame 1)"),
                          ("nonwhite_pct_2d", "2D non-white area per frame (%, clip median)")):
            g, p = look[key]["generated"], look[key]["published"]
            cell = "–" if g is None else f"{g['min']}–{g['median']}–{g['max']}"
            out.append(f"| {name} | {cell} | {p['min']}–{p['median']}–{p['max']} | "
                       f"{_within(g, p)} |")
        o = look["objects_per_scene"]
        out.append(f"| objects per scene (all / 2D / 3D) | {_paper(o['generated'])} / "
                   f"{_paper(o['generated_2d'])} / {_paper(o['generated_3d'])} | "
                   f"{o['published']} | – |")
    out += ["", f"Line/rectangle rule: {stats['line_rectangle_rule']}.", "",
            "## Difficulty per split", "",
            "| split | easy | medium | hard | unlabelled | total | paper (easy/medium/hard) |",
            "|---|---:|---:|---:|---:|---:|---:|"]
    for split, row in stats["difficulty"].items():
        c, p = row["counts"], row["paper"]
        paper = "–" if p is None else f"{p['easy']}/{p['medium']}/{p['hard']}"
        out.append(f"| {split} | {c['easy']} | {c['medium']} | {c['hard']} | "
                   f"{c.get('unlabelled', 0)} | {c['total']} | {paper} |")
    out += ["", "## Families", "", "| family | dims | scenes | templates |",
            "|---|---|---:|---:|"]
    for fam, row in stats["families"].items():
        out.append(f"| {fam} | {', '.join(row['dims'])} | {row['scenes']} | {row['templates']} |")
    rej = stats["rejected"]
    out += ["", "## Rejected candidates (validity filters)", ""]
    if rej["by_reason"]:
        out += ["| reason | candidates |", "|---|---:|"]
        out += [f"| {reason} | {k} |" for reason, k in rej["by_reason"].items()]
        out.append(f"| **total** | {rej['total']} |")
    else:
        out.append("No candidate was rejected.")
    if stats["build_seconds"] is not None:
        out += ["", f"Build time: {stats['build_seconds']:.1f} s"]
    return "\n".join(out) + "\n"


def write_datasheet(root: Path, entries: list[dict], rejected: dict[str, int],
                    build_seconds: float | None) -> Path:
    """Write ``<root>/DATASHEET.md`` and ``<root>/datasheet.json`` atomically; returns the .md path.

    ``entries``: one dict per scene with scene_id, template_id, dim ("2d"/"3d"), family, splits
    (list of split names), difficulty (easy/medium/hard; anything else counts as unlabelled),
    categories (detection categories present) and n_objects_by_category ({category: count}).
    ``rejected``: candidates rejected by the validity filters, by reason.
    """
    root = Path(root)
    stats = datasheet_stats(entries, rejected, build_seconds)
    atomic_write(root / DATASHEET_JSON, json.dumps(stats, indent=1, ensure_ascii=False) + "\n")
    md = root / DATASHEET_MD
    atomic_write(md, render_markdown(stats))
    return md
