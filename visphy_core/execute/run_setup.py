"""Building a run's pieces before any scene (`visphy_core.execute.run`), shared with re-scoring
and the one-scene commands: the judges, the reference captioning model, the check that every
call can be made and priced, the sandboxes' configuration and isolation, and how the run was set
up (`RunSetup`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Any

from omegaconf import DictConfig

from visphy_core.infra.errors import ConfigError
from visphy_core.results.summary import HeadlineColumn
from visphy_core.scoring.headline import Headline, summary_entry


@dataclass
class RunSetup:
    """How the run was set up, as its manifest and summary record it."""

    config_hash: str
    isolation: dict[str, Any]
    model: dict[str, Any]
    workers: dict[str, int]
    #: A resumed run: where the killed process's run was tracked (its manifest's ``tracking``).
    resumed_from: dict[str, dict[str, Any]]


def headline_column(headline: Headline | None) -> HeadlineColumn | None:
    """The run's headline as its summary reports it (`visphy_core.results.summary.summarise`)."""
    return HeadlineColumn(headline.name, partial(summary_entry, headline)) \
        if headline is not None else None


def _isolation(cfg: DictConfig) -> dict[str, Any]:
    """Configure the sandboxes from ``sandbox.*`` and record the isolation they provide.

    ``allow_unisolated=false`` leaves the choice to ``$VISPHY_ALLOW_UNISOLATED`` (either opt-out
    suffices); the probes run once per process.
    """
    from visphy_core.sandbox import browser, process

    allow = bool(cfg.sandbox.allow_unisolated)
    process.configure(allow_unisolated=True if allow else None)
    browser.configure(allow_unisolated=True if allow else None,
                      memory_mb=int(cfg.sandbox.browser_memory_mb))
    return {"allow_unisolated": allow or process.unisolated_allowed(),
            "process": process.isolation_level(), "browser": browser.browser_isolation_level()}


def build_judges(cfg: DictConfig, registry) -> list[tuple[str, Any]]:
    """The selected judges as (selection key, Judge) pairs (a run and re-scoring alike)."""
    judges = []
    for key, node in (cfg.get("judge") or {}).items():
        judges.append((str(key), registry.get("judges", str(node.name))(node)))
    return judges


def reference_model_of(cfg: DictConfig, registry):
    """The captioning model of ``reference.source=llm`` (a model config from conf/model/)."""
    if str(cfg.reference.source) != "llm":
        return None
    if not cfg.reference.model:
        raise ConfigError("reference.source=llm needs reference.model=<a model config name>, "
                          "e.g. reference.model=<a model config>")
    from visphy_core.config.check import compose

    node = compose([f"model={cfg.reference.model}"]).model
    return registry.get("models", str(node.name))(node)


def _check_ready(cfg: DictConfig, model, judges, reference_model) -> None:
    """Before any work: keys present, and a cost cap only where every call has a price."""
    for thing in [model, *(j for _, j in judges), reference_model]:
        if thing is not None:
            thing.check_ready()
    cap = cfg.run.get("cost_cap_usd")
    if cap is None:
        return
    reference = ([(f"reference.model={cfg.reference.model}", reference_model.cfg)]
                 if reference_model is not None and reference_model.cfg is not None else [])
    for what, node in [(f"model={cfg.model.name}", cfg.model),
                       *((f"judge={k}", j.cfg) for k, j in judges), *reference]:
        price = node.get("price") if hasattr(node, "get") else None
        if price is not None and (price.get("input_usd_per_mtok") is None
                                  or price.get("output_usd_per_mtok") is None):
            raise ConfigError(f"run.cost_cap_usd={cap:g} needs prices for every call, but "
                              f"{what} has no price (set its price.input_usd_per_mtok and "
                              "price.output_usd_per_mtok)")
