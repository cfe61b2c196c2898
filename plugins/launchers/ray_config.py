"""The Ray launcher's config (``hydra.launcher.*``) and its registration with visphy and Hydra.

``conf/hydra/launcher/ray_local.yaml`` and ``ray.yaml`` extend the schema stored here as
``hydra/launcher/schema_ray``:

* ``init``: keyword arguments of ``ray.init`` (``address: null`` starts a local cluster for the
  sweep, ``auto`` joins the cluster of the node visphy runs on, ``host:port`` a given one);
* ``remote``: Ray task options of each job (``num_cpus``, ``num_gpus``, ``memory``, ``resources``);
* ``forward_env``: names or glob patterns of the launching process's environment variables that
  every job receives (through Ray's ``runtime_env``), since the workers of an existing cluster
  do not share the shell visphy was started from. API keys are deliberately not among them: put
  them in ``$VISPHY_HOME/.env`` on the shared path (`visphy_core.calls.keys`) instead of sending
  them through the cluster's metadata store.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List

from visphy_core.api.hookspecs import hookimpl

LAUNCHER_CLASS = "hydra_plugins.visphy_launchers.ray_launcher.RayLauncher"


@dataclass
class RayLauncherConfig:
    _target_: str = LAUNCHER_CLASS
    init: Dict[str, Any] = field(default_factory=lambda: {"address": None})
    remote: Dict[str, Any] = field(default_factory=lambda: {"num_cpus": 1})
    forward_env: List[str] = field(default_factory=lambda: ["VISPHY_*", "TORCH_HOME",
                                                            "HF_HOME"])


def make_discoverable() -> None:
    """Let Hydra's plugin scan find ``hydra_plugins.visphy_launchers`` in a source checkout.

    A wheel installs that package into site-packages, where the scan (``pkgutil`` over the
    ``hydra_plugins`` namespace) finds it. An editable install maps it through setuptools'
    import hook instead, which ``pkgutil`` cannot list; so when this folder holds the package,
    the folder goes on ``sys.path`` (it contains nothing but ``hydra_plugins/``)."""
    here = Path(__file__).resolve().parent
    if (here / "hydra_plugins" / "visphy_launchers").is_dir() and str(here) not in sys.path:
        sys.path.append(str(here))


@hookimpl
def visphy_register_configs(config_store):
    make_discoverable()
    config_store.store(group="hydra/launcher", name="schema_ray", node=RayLauncherConfig,
                       provider="visphy")
