"""Parameter recovery (docs/metrics.md): how far the physical parameters a model states are
from the ground truth's, as the ``param_*`` metrics scored them (plugins/metrics/params.py).

Each ``param_*`` value is one scene's absolute error (a pair parameter: the mean over the pairs
the clip reveals), so the mean over scenes is the MAE; the count says how many scenes revealed
the parameter *and* got a usable value from the model. The paper's reference row (GPT-5 MAE on
its benchmark: e 0.17, μ 0.10, mass 0.15, speed 2.07; gravity not reported) sits beside it. Note
that visphy scores mass as the error of log mass *ratios* (scale-free), the paper as kilograms:
that column of the reference row is not comparable and left empty (`reference_table` shows the
paper's numbers with that caveat).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from visphy_core.analysis.column_views import MODEL_SUCCESS, scene_values
from visphy_core.results.load import RunData

#: column -> (short name, unit)
PARAMETERS = {
    "param_gravity_err": ("gravity", "m/s²"),
    "param_restitution_err": ("restitution", ""),
    "param_friction_err": ("friction", ""),
    "param_mass_ratio_err": ("mass ratio", "|Δ ln|"),
    "param_speed_err": ("initial speed", "m/s"),
}
#: The paper's GPT-5 MAE per parameter (None: not reported; mass in kg).
PAPER_MAE = {"param_gravity_err": None, "param_restitution_err": 0.17,
             "param_friction_err": 0.10, "param_mass_ratio_err": 0.15, "param_speed_err": 2.07}
#: visphy columns on another scale than the paper's (mass: log ratio vs kg).
NOT_COMPARABLE = ("param_mass_ratio_err",)
#: The paper's ground-truth means over its benchmark (mass in kg).
PAPER_GT_MEAN = {"param_gravity_err": 9.82, "param_restitution_err": 0.15,
                 "param_friction_err": 0.40, "param_mass_ratio_err": 1.25,
                 "param_speed_err": 2.59}
PAPER_LABEL = "paper: GPT-5 (reference)"


def param_columns(columns: list[str]) -> list[str]:
    """The parameter-recovery columns among ``columns``, in `PARAMETERS` order."""
    return [c for c in PARAMETERS if c in columns]


def _title(col: str) -> str:
    name, unit = PARAMETERS[col]
    return f"{name} MAE ↓" + (f" [{unit}]" if unit else "")


def param_table(runs: list[RunData], labels: list[str], columns: list[str],
                view: str = MODEL_SUCCESS, reference: bool = True) -> pd.DataFrame:
    """One row per run: per parameter, the MAE over the scenes that scored it and their
    count; then the paper's reference row."""
    cols = param_columns(columns)
    rows = []
    for run, label in zip(runs, labels):
        row: dict = {"run": label}
        for col in cols:
            values = scene_values(run, col, view)
            row[_title(col)] = float(values.mean()) if len(values) else np.nan
            row[f"{PARAMETERS[col][0]} n"] = int(len(values))
        rows.append(row)
    if reference and cols:
        ref: dict = {"run": PAPER_LABEL}
        for col in cols:
            value = PAPER_MAE[col]
            ref[_title(col)] = np.nan if value is None or col in NOT_COMPARABLE else value
            ref[f"{PARAMETERS[col][0]} n"] = np.nan
        rows.append(ref)
    return pd.DataFrame(rows)


def reference_table() -> pd.DataFrame:
    """The paper's parameter table beside visphy's columns: its ground-truth mean and GPT-5's
    MAE per parameter, and whether visphy's error is on the same scale."""
    rows = []
    for col, (name, unit) in PARAMETERS.items():
        same_scale = col not in NOT_COMPARABLE
        rows.append({"parameter": name, "visphy column": col, "visphy unit": unit or "—",
                     "paper GT mean": PAPER_GT_MEAN[col],
                     "paper GPT-5 MAE": np.nan if PAPER_MAE[col] is None else PAPER_MAE[col],
                     "comparable": "yes" if same_scale else "no (paper: kg; visphy: log ratio)"})
    return pd.DataFrame(rows)
