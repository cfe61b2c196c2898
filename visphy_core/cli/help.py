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
    lines += ["", "examples:", *(f"  {example}" for example in _run_examples()),
              "", "`visphy run --cfg job` prints the whole composed config; "
              "`visphy run --info` Hydra's view of it."]
    return "\n".join(lines)


def _run_examples() -> list[str]:
    """Runs written with the installed config tree's options: the defaults spelt out, then
    another option of the same kind as each default (`sibling_option`), and a study of both."""
    model, engine, dataset = (default_option(g) for g in ("model", "engine", "dataset"))
    other = {g: sibling_option(g) for g in ("model", "engine", "dataset")}
    return [f"visphy model={model} engine={engine} dataset={dataset}   (the defaults)",
            f"visphy model={other['model']} engine={other['engine']} "
            f"dataset={other['dataset']} metrics=fast",
            f"visphy --multirun model={model},{other['model']} engine={engine},{other['engine']}"
            "   (a study)"]


def sibling_option(group: str) -> str:
    """The first other option of ``group`` made like its default: the same schema and, where
    the default names one, the same ``source`` (``dataset``: another split of the default
    dataset's source); the default itself where there is none."""
    default = default_option(group)
    mine = option_config(group, default, schema=True)
    for name in config_options().get(group, []):
        theirs = option_config(group, name, schema=True)
        if name != default and all(theirs.get(k) == mine[k] for k in ("defaults", "source")
                                   if k in mine):
            return name
    return default


def default_option(group: str) -> str:
    """The root config's default option of ``group`` (``engine`` → the default engine's config
    name), ``...`` where the defaults list has none."""
    return _default_options().get(group, "...")


def option_config(group: str, option: str, schema: bool = False) -> dict:
    """The keys the option's own YAML file sets (``dataset``, ``mini`` → its ``source``,
    ``split``, …), uncomposed, with its ``defaults`` list where ``schema``; empty where the
    installed config tree has no such file."""
    from omegaconf import OmegaConf

    from visphy_core.config.tree import option_node

    node = option_node(group, option)
    values = OmegaConf.to_container(node) if node is not None else None
    if not isinstance(values, dict):
        return {}
    return {k: v for k, v in values.items() if schema or k != "defaults"}


def _default_options() -> dict[str, str]:
    """The root config's defaults list: group → default option."""
    from visphy_core.config.tree import root_node

    out = {}
    for item in root_node().get("defaults", []):
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
                     f"run takes overrides such as engine={default_option('engine')})")


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
