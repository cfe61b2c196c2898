"""``python -m visphy_core rate PATH... --rater ID``: serve the model-blind rating page locally.

Collects every generated clip of the run directories under the PATHs (`visphy_core.human`),
prints the page's URL and serves until Ctrl-C; ratings go to each run's
``human_ratings.jsonl`` as they are given, so stopping at any point loses nothing and the same
command resumes where the rater stopped.
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="visphy rate",
        description="Rate generated clips against the ground truth, 1-5, on a local page that "
                    "hides which model and engine made each clip.")
    p.add_argument("paths", nargs="+", metavar="PATH",
                   help="run directories, or folders holding them (e.g. visphy-out/runs)")
    p.add_argument("--rater", required=True,
                   help="your rater id (the same every session: it seeds your order)")
    p.add_argument("--host", default="127.0.0.1", help="loopback address to bind")
    p.add_argument("--port", type=int, default=8765, help="port (0: any free port)")
    p.add_argument("--verbose", action="store_true", help="log every request")
    return p


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def rate_command(argv: list[str]) -> int:
    from visphy_core.human.items import collect_items, find_run_dirs
    from visphy_core.human.media import PlayableCopies
    from visphy_core.human.server import RatingServer, RatingSession
    from visphy_core.human.store import RATINGS_FILE, check_rater

    args = _parser().parse_args(argv)
    check_rater(args.rater)
    run_dirs = find_run_dirs(args.paths)
    items = collect_items(run_dirs)
    session = RatingSession(items, args.rater)
    with tempfile.TemporaryDirectory(prefix="visphy-rate-") as tmp:
        try:
            server = RatingServer(session, PlayableCopies(Path(tmp)), host=args.host,
                                  port=args.port, quiet=not args.verbose)
        except OSError as exc:
            from visphy_core.infra.errors import UserError

            raise UserError(f"cannot listen on {args.host}:{args.port}: {exc.strerror or exc} "
                            "(--port 0 picks a free port)") from None
        left = len(items) - len(session.rated)
        print(f"rating {len(items)} clip(s) from {len(run_dirs)} run(s) as {args.rater}: "
              f"{left} left to rate")
        print(f"open {server.url}  (Ctrl-C to stop)", flush=True)
        # Ctrl-C and `kill` stop cleanly even when the parent ignored SIGINT (a background job
        # of a non-interactive shell, a test runner's worker): a child inherits SIG_IGN.
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _interrupt)
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            server.server_close()
    print(f"\nstopped: {session.written} rating(s) saved this session to {RATINGS_FILE} in "
          "each run directory", file=sys.stderr)
    return 0
