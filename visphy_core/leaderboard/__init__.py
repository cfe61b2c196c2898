"""A static leaderboard site from finished runs (``visphy leaderboard RUN_OR_STUDY... -o DIR``).

One concern per module: `entries` (a run as a row), `ties` (which differences the paired
bootstrap separates), `breakdowns` (by difficulty, template, label, 2D/3D; the model × engine
matrix), `references` (rows the user adds from a file, never ranked), `clips` (the run reports
and best/worst clips copied in, media capped), `plots` (inline SVG), `metric_pages` (from the
metric registry), `html` and `pages` (the pages), `site` (`build_site`, which writes them).
"""

from visphy_core.leaderboard.site import SiteOptions, build_site

__all__ = ["SiteOptions", "build_site"]
