"""Parameter recovery (MISSION §6 item 6): how far the physical parameters a model states are
from the ground truth's, as the ``param_*`` metrics scored them (plugins/metrics/params.py).

Each ``param_*`` value is one scene's absolute error (a pair parameter: the mean over the pairs
the clip reveals), so the mean over scenes is the MAE; the count says how many scenes revealed
the parameter *and* got a usable value from the model. The paper's reference row (GPT-5 MAE on
VisPhyBench: e 0.17, μ 0.10, mass 0.15, speed 2.07; gravity not reported) sits beside it. Note
that visphy scores mass as the error of log mass *ratios* (scale-free), the paper as kilograms:
that column of the reference row is not comparable and left empty.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from visphy_core.analysis.columns import MODEL_SUCCESS, scene_values
from visphy_core.analysis.load import RunData

#: column -> (short name, unit)
PARAMETERS = {
    "param_gravity_err": ("gravity", "m/s²"),
    "param_restitution_err": ("restitution", ""),
    "param_friction_err": ("friction", ""),
    "param_mass_ratio_err": ("mass ratio", "|Δ ln|"),
    "param_speed_err": ("initial speed", "m/s"),
}
#: The paper's GPT-5 MAE per parameter (None: not reported or not comparable).
PAPER_MAE = {"param_gravity_err": None, "param_restitution_err": 0.17,
             "param_friction_err": 0.10, "param_mass_ratio_err": None, "param_speed_err": 2.07}
#: The paper's ground-truth means over VisPhyBench (kg for mass).
PAPER_GT_MEAN = {"gravity": 9.82, "restitution": 0.15, "friction": 0.40, "mass (kg)": 1.25,
                 "initial speed": 2.59}
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
            ref[_title(col)] = np.nan if value is None else value
            ref[f"{PARAMETERS[col][0]} n"] = np.nan
        rows.append(ref)
    return pd.DataFrame(rows)
