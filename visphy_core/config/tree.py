"""The installed config tree (``visphy_conf``) read as files, uncomposed: the root config's own
keys and an option's YAML, for help texts and command defaults that must not start Hydra."""

from __future__ import annotations

from importlib import resources
from typing import Any

from omegaconf import OmegaConf

#: The root config's file in the tree (not a run's config file).
ROOT_FILE = "config.yaml"


def root_node() -> Any:
    """The root config file as written (its ``defaults`` list and its own keys)."""
    return OmegaConf.create(resources.files("visphy_conf").joinpath(ROOT_FILE).read_text())


def option_node(group: str, option: str) -> Any | None:
    """An option's own YAML file (``dataset``, ``mini``), uncomposed; None where the installed
    tree has no such file."""
    path = resources.files("visphy_conf").joinpath(group, f"{option}.yaml")
    return OmegaConf.create(path.read_text()) if path.is_file() else None
