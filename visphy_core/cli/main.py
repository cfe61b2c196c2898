"""Command line: ``visphy [COMMAND] [ARGS]`` (also ``python -m visphy_core …``).

``visphy --help`` lists the commands with one line each (`COMMANDS`); ``visphy run --help`` lists
the run's config groups and their options. A first word that is not a command and not an
override is answered with the closest command; a ``--flag value`` where an override belongs
with the override to write (``--engine E`` → ``engine=E``).

Commands:
  run            evaluate a model on a dataset (the default: overrides alone are a run)
  plugins        list installed plugins and what each registers (also: --plugins)
  metrics        list installed metrics: direction, family, kind, weights, availability here
  setup          install the vendored JavaScript libraries (npm ci into the asset cache)
  build-dataset  generate a built dataset: build-dataset [--split S] [--seed N] [--data-dir DIR]
  ground-truth   a dataset's normalisation anchors and twin renders ahead of any run, into
                 paths.ground_truth_dir: ground-truth [--workers N] [dataset=… engine=… …]
  normalise      resample a foreign video to a reference clip: normalise IN --like REF -o OUT
  render         extract, render and score one reply: render REPLY --engine E [--scene ID]
  intervene      change physical parameters, re-simulate, render side by side:
                 intervene --scene ID (--gt | --run RUN_DIR) --set gravity=-20 [--set ...]
  rate           model-blind human rating page on localhost: rate PATH... --rater ID
  score          re-score a finished run (other metrics/judges; no model call, no render):
                 score RUN_DIR [metrics.names=[...] | judge=... | ...] [--in-place]
  analyse        tables and figures from finished runs (leaderboard, bootstrap CIs, Spearman):
                 analyse PATH... [-o OUT] [--study NAME] [--metrics a,b]
  report         HTML report that opens from disk: report RUN_DIR (a run) or
                 report RUN_DIR RUN_DIR... [-o OUT] [--title T] (a study)
  leaderboard    static leaderboard site from runs and studies (ties, breakdowns, clips):
                 leaderboard RUN_OR_STUDY... -o SITE [--reference FILE] [--labels FILE]
  merge          one run from its shards (dataset.shard=i/n), one MLflow parent run:
                 merge SHARD_RUN_DIR... -o MERGED_RUN_DIR [--partial]
  track          log finished runs to MLflow after the fact (a run whose tracking failed):
                 track RUN_DIR... [--uri URI] [--experiment NAME] [--again]
  export         a run's scores as a tidy table: export RUN_DIR --format parquet|csv [-o OUT]
  export-dataset a dataset as a Hugging Face folder: export-dataset --format hf -o DIR [dataset=…]
Anything else is a Hydra run: ``python -m visphy_core engine=E model=M dataset=D``.

Bad input (a config value, a missing dataset, a plugin that does not load, Chromium missing) is
reported as one line, ``error: ...`` on stderr, exit status 2; a fault of the machine (a full
disk, a read-only or forbidden folder) likewise, exit status 74. ``--traceback`` (or
``VISPHY_TRACEBACK=1``) shows the full traceback instead, for debugging.
"""

# size: the command table and its lazy handlers (a few lines per command: each command's code is
# in its own module), the top-level error reporting and the Hydra entry
from __future__ import annotations

import argparse
import os
import sys
from types import TracebackType
from typing import Callable

from visphy_core.cli.help import (
    HYDRA_FLAGS,
    VALUE_FLAGS,
    default_option,
    flag_as_override,
    run_usage,
    unknown_command,
)
from visphy_core.config.check import LAST_HYDRA_MODE, check_inputs, check_overrides
from visphy_core.infra.errors import HostFault, UserError, describe_host_fault, host_fault

#: A ValueError / FileNotFoundError raised below these (a dataset plugin loading or building its
#: data) is about the user's dataset, not a bug.
DATASET_MODULES = ("visphy_core.execute.datasets",)




def _overrides_of(argv: list[str]) -> list[str]:
    out, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in VALUE_FLAGS:
            skip = True
        elif not arg.startswith("-"):
            out.append(arg)
    return out


def _traceback_wanted() -> bool:
    return os.environ.get("VISPHY_TRACEBACK", "").strip().lower() not in ("", "0", "false", "no")


def _external_user_errors() -> tuple[type[BaseException], ...]:
    """Error types of other modules that always mean bad input or a missing prerequisite."""
    types: list[type[BaseException]] = []
    for module, name in (("visphy_core.api.registry", "PluginError"),
                         ("visphy_core.sandbox.browser", "BrowserUnavailable"),
                         ("visphy_core.infra.js_assets", "AssetsMissing")):
        try:
            mod = __import__(module, fromlist=[name])
            types.append(getattr(mod, name))
        except Exception:  # noqa: BLE001 - a module that does not import cannot have raised
            continue
    return tuple(types)


def _raise_site(tb: TracebackType | None) -> str:
    name = ""
    while tb is not None:
        name = tb.tb_frame.f_globals.get("__name__", "")
        tb = tb.tb_next
    return name


def _in_dataset_loading(tb: TracebackType | None) -> bool:
    while tb is not None:
        if tb.tb_frame.f_globals.get("__name__", "").startswith(DATASET_MODULES):
            return True
        tb = tb.tb_next
    return False


def is_user_error(exc: BaseException) -> bool:
    """Whether ``exc`` is the user's input or machine rather than a bug: a `UserError` (config
    errors included), a plugin that fails to load, Chromium or the browser libraries missing,
    a fault of the machine (`host_fault`: a full disk, a read-only or forbidden folder), or a
    ValueError / FileNotFoundError raised by dataset loading (a missing root, unknown scene
    ids, an empty selection, a malformed index file)."""
    if isinstance(exc, UserError) or isinstance(exc, _external_user_errors()):
        return True
    if host_fault(exc) is not None:
        return True
    tb = exc.__traceback__
    if isinstance(exc, (FileNotFoundError, NotADirectoryError)) and _in_dataset_loading(tb):
        return True
    return isinstance(exc, ValueError) and (_raise_site(tb).startswith(DATASET_MODULES)
                                            or _in_dataset_loading(tb))


def one_line(exc: BaseException) -> str:
    text = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return text or type(exc).__name__


def report(exc: BaseException) -> int:
    """Print ``exc`` as one ``error:`` line; its exit status (2, or the error's own
    ``exit_code``: 74 for a fault of the machine)."""
    fault = None if isinstance(exc, UserError) else host_fault(exc)
    if fault is not None:
        print(f"error: {describe_host_fault(fault)}; then rerun the same command",
              file=sys.stderr)
        return HostFault.exit_code
    print(f"error: {one_line(exc)}", file=sys.stderr)
    return int(getattr(exc, "exit_code", 2))


def no_options(name: str, description: str, argv: list[str]) -> None:
    """The argument check of a command that takes none: ``--help`` prints its line and exits;
    anything else is argparse's one-line error (exit status 2) instead of being ignored."""
    argparse.ArgumentParser(prog=f"visphy {name}", description=description).parse_args(argv)


def visphy_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("visphy")
    except PackageNotFoundError:
        return "(not installed)"


def _table_width() -> int | None:
    """A terminal's own width (cells wrap to fit it); 160 columns for a pipe or a file."""
    return None if sys.stdout.isatty() else 160


def cmd_plugins(argv: list[str]) -> int:
    no_options("plugins", "List the installed plugins (entry points of the 'visphy' group): "
               "the distribution each comes from, what it registers and the hooks it "
               "implements.", argv)
    from rich.console import Console
    from rich.table import Table

    from visphy_core.api.registry import describe_plugins

    table = Table(title="visphy plugins")
    for col in ("plugin", "distribution", "registers", "hooks"):
        table.add_column(col, overflow="fold", no_wrap=col == "plugin")
    for info in describe_plugins():
        regs = "; ".join(f"{kind}: {', '.join(sorted(names))}"
                         for kind, names in sorted(info.registers.items()))
        table.add_row(info.name, f"{info.distribution} {info.version}", regs or "—",
                      ", ".join(h.removeprefix("visphy_") for h in info.hooks))
    Console(width=_table_width()).print(table)
    return 0


def cmd_setup(argv: list[str]) -> int:
    no_options("setup", "Install the vendored JavaScript libraries the browser engines and "
               "the 3D physics need (npm ci of the pinned lock file into the asset cache; "
               "needs node and npm).", argv)
    from visphy_core.api.assets import install_assets

    for path in install_assets():
        print(f"browser engine libraries ready in {path}")
    return 0


def cmd_build_dataset(argv: list[str]) -> int:
    from visphy_core.cli.build_dataset import cmd_build_dataset as build_dataset

    return build_dataset(argv)


def cmd_normalise(argv: list[str]) -> int:
    import shutil
    from pathlib import Path

    from visphy_core.infra.video import (
        clip_matches,
        decode_video,
        decode_video_timed,
        encode_video,
        resample_by_time,
    )

    parser = argparse.ArgumentParser(
        prog="visphy normalise",
        description="Resample any video to a reference clip's fps, frame count and size by its "
                    "own timestamps (frame k = the frame on screen at k / fps; aspect kept, "
                    "padded with white). A video that already matches is copied unchanged.")
    parser.add_argument("video", help="the foreign video (a baseline's or upstream output)")
    parser.add_argument("--like", required=True, help="the reference clip to match")
    parser.add_argument("-o", "--output", required=True)
    args = parser.parse_args(argv)
    try:  # a missing or undecodable file is the user's input: one line
        frames, times, info = decode_video_timed(Path(args.video))
        _, target = decode_video(Path(args.like))
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(f"normalise: {one_line(exc)}") from None
    source = (f"{args.video}: {info.n_frames} frames {info.width}x{info.height} "
              f"@ {info.fps:g} fps")
    if clip_matches(info, target):
        out_path = Path(args.output)
        out_path.parent.mkdir(parents=True, exist_ok=True)
        if Path(args.video).resolve() != out_path.resolve():
            shutil.copyfile(args.video, out_path)
        print(f"{source} already matches {args.like}: copied byte for byte to {args.output} "
              "(no re-encode)")
        return 0
    out = resample_by_time(frames, times, target)
    encode_video(out, Path(args.output), target.fps)
    print(f"{source} -> {args.output}: {target.n_frames} frames {target.width}x{target.height} "
          f"@ {target.fps:g} fps (resampled by timestamp)")
    return 0


def cmd_metrics(argv: list[str]) -> int:
    """Every registered metric: direction, family, kind, range, and whether it runs here (the
    reasons a metric cannot, with how to fix them, follow the table, each once)."""
    no_options("metrics", "List the installed metrics: direction (higher or lower is "
               "better), family, kind, range, and whether each runs here (with what to install "
               "or download where it does not).", argv)
    from rich.console import Console
    from rich.table import Table

    from visphy_core.api.registry import get_registry

    registry = get_registry()
    table = Table(title="visphy metrics")
    for col in ("metric", "dir", "family", "kind", "range", "here"):
        table.add_column(col, no_wrap=col == "metric", overflow="fold")
    reasons: dict[str, list[str]] = {}
    for name in sorted(registry.metrics, key=lambda n: (registry.get("metrics", n).family, n)):
        d = registry.get("metrics", name).describe()
        lo, hi = d["range"]
        why = d["unavailable"]
        if why is not None:
            reasons.setdefault(why, []).append(name)
        here = "available" if why is None else f"unavailable [{list(reasons).index(why) + 1}]"
        table.add_row(name, "↑" if d["direction"] == "higher" else "↓", d["family"], d["kind"],
                      f"{lo:g}…{hi:g}", here)
    console = Console(width=_table_width())
    console.print(table)
    for i, (why, names) in enumerate(reasons.items(), 1):
        console.print(f"[{i}] {', '.join(names)}: {why}", soft_wrap=True)
    return 0


def cmd_render(argv: list[str]) -> int:
    from visphy_core.cli.render import render_command

    return render_command(argv)


def cmd_intervene(argv: list[str]) -> int:
    from visphy_core.cli.intervene import intervene_command

    return intervene_command(argv)


def cmd_rate(argv: list[str]) -> int:
    from visphy_core.cli.rate import rate_command

    return rate_command(argv)


def cmd_score(argv: list[str]) -> int:
    from visphy_core.cli.score import cmd_score as score

    return score(argv)


def cmd_analyse(argv: list[str]) -> int:
    from visphy_core.cli.analysis import cmd_analyse as analyse

    return analyse(argv)


def cmd_report(argv: list[str]) -> int:
    from visphy_core.cli.report import main as report_command

    return report_command(argv)


def cmd_leaderboard(argv: list[str]) -> int:
    from visphy_core.cli.leaderboard import main as leaderboard

    return leaderboard(argv)


def cmd_merge(argv: list[str]) -> int:
    from visphy_core.cli.merge import cmd_merge as merge

    return merge(argv)


def cmd_track(argv: list[str]) -> int:
    from visphy_core.cli.track import cmd_track as track

    return track(argv)


def cmd_export(argv: list[str], dataset: bool = False) -> int:
    from visphy_core.cli import export

    return (export.cmd_export_dataset if dataset else export.cmd_export)(argv)


def cmd_ground_truth(argv: list[str]) -> int:
    from visphy_core.cli.ground_truth import cmd_ground_truth as ground_truth

    return ground_truth(argv)


#: Every command: its handler and its line in ``visphy --help``.
COMMANDS: dict[str, tuple[Callable[[list[str]], int], str]] = {
    "run": (lambda argv: cmd_run(argv),
            "evaluate a model on a dataset: run [group=option key=value ...] (the default)"),
    "score": (cmd_score, "re-score a finished run with other metrics or judges, no model call"),
    "report": (cmd_report, "the HTML report of a run, or of several runs as a study"),
    "analyse": (cmd_analyse, "tables and figures from finished runs (leaderboard, CIs, ...)"),
    "leaderboard": (cmd_leaderboard, "a static leaderboard site from runs and studies"),
    "merge": (cmd_merge, "one run from the shards of a sharded run (dataset.shard=i/n)"),
    "track": (cmd_track, "log finished runs to MLflow after the fact (tracking that failed)"),
    "export": (cmd_export, "a run's scores as one tidy table (Parquet or CSV) for pandas/polars"),
    "export-dataset": (lambda argv: cmd_export(argv, dataset=True),
                       "a dataset as a Hugging Face `datasets` folder"),
    "render": (cmd_render, "render one model reply, and score it against a scene (--scene)"),
    "intervene": (cmd_intervene, "change physical parameters, re-simulate, render side by side"),
    "rate": (cmd_rate, "the model-blind human rating page on localhost"),
    "build-dataset": (cmd_build_dataset, "generate a dataset that is built, not downloaded"),
    "ground-truth": (cmd_ground_truth, "a dataset's normalisation anchors, ahead of any run"),
    "normalise": (cmd_normalise, "resample a foreign video to a reference clip's contract"),
    "metrics": (cmd_metrics, "the installed metrics: direction, family, availability here"),
    "plugins": (cmd_plugins, "the installed plugins and what each registers"),
    "setup": (cmd_setup, "install the vendored JavaScript libraries (npm ci)"),
}
SUBCOMMANDS = {name: handler for name, (handler, _) in COMMANDS.items() if name != "run"}


def usage() -> str:
    """``visphy --help``: every command with its line, then how a run is written."""
    width = max(len(name) for name in COMMANDS)
    lines = ["usage: visphy [COMMAND] [ARGS]", "",
             "visphy evaluates whether a model understands physics by having it write a "
             "simulator.", "", "commands:"]
    lines += [f"  {name:<{width}}  {summary}" for name, (_, summary) in COMMANDS.items()]
    defaults = " ".join(f"{g}={default_option(g)}" for g in ("model", "engine", "dataset"))
    lines += ["", f"A run is the default command: `visphy {defaults}` is `visphy run ...`.",
              "`visphy run --help` lists the config groups and their options; "
              "`visphy COMMAND --help` a command's own options.",
              "`--traceback` (or VISPHY_TRACEBACK=1) shows full tracebacks; "
              "`visphy --version` the version."]
    return "\n".join(lines)


#: third-party loggers whose INFO lines are per call (httpx's "HTTP Request: POST ...",
#: google-genai's "AFC is enabled ...", the SDKs' retry notes): under Hydra's stdout logging
#: (root at INFO) they would interleave with the progress bars, one per model or judge call.
#: httpx2/httpcore2 are the names the HTTP stack goes by where the SDKs ship the renamed fork.
CHATTY_LOGGERS = ("httpx", "httpx2", "httpcore", "httpcore2", "google_genai", "openai",
                  "anthropic")


def quiet_chatty_loggers() -> None:
    """Keep the HTTP clients' and SDKs' per-call INFO lines out of a run's output (warnings
    and errors still show)."""
    import logging

    for name in CHATTY_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)


def _skip_hydra_mode_compose() -> None:
    """Hydra composes the whole config once only to read ``hydra.mode`` (``Hydra.get_mode``,
    about 0.5 s of every command) before it composes it again for the job. The check above
    composed the same overrides and found no mode set, which is what Hydra would return; so it
    is answered without composing (Hydra then picks RUN, or MULTIRUN with ``-m``)."""
    from hydra._internal.hydra import Hydra

    Hydra.get_mode = lambda self, config_name, overrides: None


def run_hydra(argv: list[str]) -> int:
    import hydra
    from hydra.core.global_hydra import GlobalHydra

    from visphy_core.api.registry import get_registry

    show_traceback = _traceback_wanted()
    quiet_chatty_loggers()  # the pre-flight below already calls servers
    checked = False
    try:
        get_registry()  # plugins store their structured configs before Hydra composes
        if not any(a in HYDRA_FLAGS or a.startswith("--info") for a in argv):
            LAST_HYDRA_MODE.clear()
            check_overrides(_overrides_of(argv), inputs=True)
            checked = LAST_HYDRA_MODE == [None]
    except Exception as exc:  # noqa: BLE001
        if show_traceback or not is_user_error(exc):
            raise
        return report(exc)
    GlobalHydra.instance().clear()
    if checked:
        _skip_hydra_mode_compose()

    @hydra.main(version_base="1.3", config_path="pkg://visphy_conf", config_name="config")
    def _main(cfg) -> dict:
        from visphy_core.execute.run import run_experiment

        quiet_chatty_loggers()  # again in the job: a launcher may run it in another process
        try:
            check_inputs(cfg)
            return run_experiment(cfg)  # a study's job record reads the run dir from it
        except Exception as exc:  # noqa: BLE001
            if show_traceback or not is_user_error(exc):
                raise
            # Hydra prints a traceback for any exception out of the task; SystemExit passes.
            raise SystemExit(report(exc)) from None

    sys.argv = [sys.argv[0]] + argv
    _main()
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--traceback" in argv:
        argv = [a for a in argv if a != "--traceback"]
        os.environ["VISPHY_TRACEBACK"] = "1"
    if _traceback_wanted():
        os.environ.setdefault("HYDRA_FULL_ERROR", "1")
    from visphy_core.infra.secrets import install_log_redaction

    install_log_redaction()
    try:
        from visphy_core.calls.keys import register_env_files

        register_env_files()  # a bad .env is one line; its secrets are redacted everywhere
    except UserError as exc:
        if _traceback_wanted():
            raise
        return report(exc)
    if not argv or argv[0] in ("--help", "-h", "help"):
        if argv:
            print(usage())
            return 0
    if argv and argv[0] in ("--version", "-V"):  # visphy's, not Hydra's
        import hydra

        print(f"visphy {visphy_version()} (Hydra {hydra.__version__}, Python "
              f"{sys.version.split()[0]})")
        return 0
    if argv and argv[0] == "run" and any(a in ("--help", "-h") for a in argv[1:]):
        print(run_usage())
        return 0
    if argv and argv[0] in COMMANDS:
        try:
            return COMMANDS[argv[0]][0](argv[1:])
        except Exception as exc:  # noqa: BLE001
            if _traceback_wanted() or not is_user_error(exc):
                raise
            return report(exc)
    if "--plugins" in argv:
        return cmd_plugins([])
    if argv and not argv[0].startswith("-") and "=" not in argv[0] \
            and not argv[0].startswith(("+", "~")):
        return report(unknown_command(argv[0], list(COMMANDS)))
    return cmd_run(argv)


def cmd_run(argv: list[str]) -> int:
    """A run (``visphy run ...`` or overrides alone), after the flag check."""
    problem = flag_as_override(argv)
    if problem is not None:
        return report(problem)
    return run_hydra(argv)
