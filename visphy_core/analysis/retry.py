"""The retry ablation (docs/studies.md): model success after the first attempt, and after one repair
call, beside the paper's published rates for the engines that declare them (`Engine.paper_retry`).

A scene succeeded at the first attempt when the model's own program gave a clip and no first
failure was recorded (``first_failure_class`` is empty); after the retry, when it succeeded at
all (``model_success``, one repair call at most). Rates are over the evaluable scenes (an
``infra_error`` or ``data_error`` scene says nothing about the model). A run made with
``run.retry=false`` has no second attempt: its two rates agree by construction.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from visphy_core.results.load import RunData
from visphy_core.results.row import NOT_EVALUABLE



def paper_rates() -> dict[str, tuple[float, float]]:
    """The paper's success rates (first attempt, with one retry) of each installed engine that
    declares them (`visphy_core.api.engine.Engine.paper_retry`)."""
    from visphy_core.api.registry import get_registry

    registry = get_registry()
    out = {}
    for name in sorted(registry.engines):
        rates = getattr(registry.get("engines", name), "paper_retry", None)
        if rates is not None:
            out[name] = (float(rates[0]), float(rates[1]))
    return out


def retry_table(runs: list[RunData], labels: list[str], reference: bool = True) -> pd.DataFrame:
    """One row per run: retry on/off, evaluable scenes, successes and rates at the first
    attempt and after one retry, and the scenes the repair call rescued; then the paper's."""
    rows = []
    for run, label in zip(runs, labels):
        df = run.table
        retry = (run.config.get("run") or {}).get("retry")
        if df.empty:
            ev = df
        else:
            ev = df[~df["failure_class"].isin(NOT_EVALUABLE)]
        ok = ev["model_success"].astype(bool) if len(ev) else pd.Series(dtype=bool)
        first = ok & ev["first_failure_class"].isna() if len(ev) else ok
        n = len(ev)
        rows.append({"run": label, "engine": run.engine,
                     "retry": "" if retry is None else str(bool(retry)).lower(),
                     "n_evaluable": n, "first attempt": int(first.sum()),
                     "after retry": int(ok.sum()), "rescued": int((ok & ~first).sum()),
                     "success (first)": first.mean() if n else np.nan,
                     "success (retry)": ok.mean() if n else np.nan})
    if reference:
        for engine, (first, after) in paper_rates().items():
            rows.append({"run": f"paper: {engine} (reference)", "engine": engine,
                         "retry": "true", "n_evaluable": np.nan, "first attempt": np.nan,
                         "after retry": np.nan, "rescued": np.nan,
                         "success (first)": first, "success (retry)": after})
    return pd.DataFrame(rows)
