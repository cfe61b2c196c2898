"""What ``visphy --help`` and ``visphy run --help`` print, and the one-line answers to a
mistyped command or a ``--flag`` where an override belongs (`visphy_core.cli.main`)."""

from __future__ import annotations

from visphy_core.infra.errors import UserError

#: Hydra's flags that are not followed by a value.
HYDRA_FLAGS = ("--help", "-h", "--hydra-help", "--info", "--cfg", "-c", "--resolve",
               "--package", "-p", "--shell-completion", "-sc")
#: Hydra flags followed by a value that is not an override.
VALUE_FLAGS = ("--config-path", "-cp", "--config-name", "-cn", "--config-dir", "-cd",
               "--experimental-rerun")
#: Flags a run takes (Hydra's and visphy's own); any other ``--flag`` is a misplaced override.
RUN_FLAGS = (*HYDRA_FLAGS, *VALUE_FLAGS, "--multirun", "-m", "--traceback", "--plugins",
             "--version")


def config_options() -> dict[str, list[str]]:
    """Each config group of the installed config tree (``visphy_conf``) and its options."""
    from importlib import resources

    root = resources.files("visphy_conf")
    groups: dict[str, list[str]] = {}

    def walk(node, prefix: str) -> None:
        for entry in sorted(node.iterdir(), key=lambda e: e.name):
            if not entry.is_dir() or entry.name.startswith(("_", ".")):
                continue
            names = sorted(e.name[:-5] for e in entry.iterdir() if e.name.endswith(".yaml"))
            if names:
                groups[prefix + entry.name] = names
            walk(entry, f"{prefix}{entry.name}/")

    walk(root, "")
    return groups


def run_usage() -> str:
    """``visphy run --help``: the config groups a run is composed from, and what to try."""
    lines = ["usage: visphy run [group=option ...] [key=value ...]", "",
             "config groups (pick one option each; the default is marked *):"]
    defaults = _default_options()
    for group, names in config_options().items():
        if group.startswith("hydra/") and group != "hydra/launcher":
            continue
        shown = ", ".join(f"{n}*" if defaults.get(group) == n else n for n in names)
        lines.append(f"  {group}: {shown}")
    lines += ["", "examples:",
              "  visphy model=gpt5 engine=threejs dataset=visphybench_test",
              "  visphy model=oracle engine=p5 dataset=mini metrics=fast",
              "  visphy --multirun model=gpt5,claude engine=threejs,p5   (a study)",
              "", "`visphy run --cfg job` prints the whole composed config; "
              "`visphy run --info` Hydra's view of it."]
    return "\n".join(lines)


def _default_options() -> dict[str, str]:
    """The root config's defaults list: group → default option."""
    from importlib import resources

    from omegaconf import OmegaConf

    text = resources.files("visphy_conf").joinpath("config.yaml").read_text()
    out = {}
    for item in OmegaConf.create(text).get("defaults", []):
        if isinstance(item, str) or not hasattr(item, "items"):
            continue
        for key, value in item.items():
            key = str(key).removeprefix("override ")
            if value is not None:
                out[key] = str(value)
    return out


def unknown_command(word: str, commands: list[str]) -> UserError:
    import difflib

    close = difflib.get_close_matches(word, commands, n=1, cutoff=0.6)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    return UserError(f"unknown command '{word}'{hint} (`visphy --help` lists the commands; a "
                     "run takes overrides such as engine=threejs)")


def flag_as_override(argv: list[str]) -> UserError | None:
    """A ``--key value`` or ``--key=value`` where an override ``key=value`` belongs."""
    known = set(RUN_FLAGS)
    for i, arg in enumerate(argv):
        if not arg.startswith("--") or arg.split("=")[0] in known or arg == "--":
            continue
        key, _, value = arg[2:].partition("=")
        if not value and i + 1 < len(argv) and not argv[i + 1].startswith("-"):
            value = argv[i + 1]
        example = f"{key.replace('-', '_')}={value or '...'}"
        return UserError(f"'{arg}' is not an option of a run: write overrides as key=value, "
                         f"e.g. {example} (`visphy run --help` lists the config groups)")
    return None
