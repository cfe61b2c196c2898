"""HTML reports of runs and studies: self-contained folders that open from disk (``file://``).

* `write_run_report`: one run — header, leaderboard with its plots (the headline with its
  interval, per-family bars), success and failure counts, then every scene with its
  ground-truth and generated clips under one play/scrub control, the key frames, its per-frame
  PSNR curve and track overlay (inline SVG), the model's analysis, program and spec S beside the
  ground truth's, scores, judge verdicts, failure class and logs.
* `write_study_report`: several runs — the leaderboard first, then the analysis' tables and
  figures, then links to each run's report.

No page loads anything from the network (no CDN, no server); model-written text is escaped
and a Content Security Policy lets only the report's own script run.
"""

from visphy_core.report.run_report import write_run_report
from visphy_core.report.study_report import write_study_report

__all__ = ["write_run_report", "write_study_report"]
