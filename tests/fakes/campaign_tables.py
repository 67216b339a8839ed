"""Campaign tables (docs/campaign-table.md) generated from the dissertation's tables.

Group tables: each sample's true properties scatter around a Table 4.2/4.3 mean with that
table's between-replicate SD (% of mean); the "estimate" adds a relative estimation error with
the standard error written in the ``_se`` column. Parameters follow from the properties by the
chain geometry (eqs. 3.32-3.38): E_sigma = (L/n)/(pi D^2/4) k_sigma, E_tau = k_tau/(pi D), ...
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

PROPS = ("E_sigma", "eta_sigma", "E_tau", "eta_tau")
PARAMS = ("k_sigma", "b_sigma", "k_tau", "b_tau")

# medium: (E_sigma 1e12, SD %), (eta_sigma 1e5, SD %), (E_tau 1e12, SD %), (eta_tau 1e5, SD %)
TABLE_4_2 = {
    "Water": ((3.22, 0.59), (3.07, 1.82), (2.11, 0.82), (5.18, 0.05)),
    "Milk": ((3.39, 0.07), (3.96, 0.12), (2.31, 0.02), (5.55, 0.05)),
    "Syrup-1": ((3.97, 0.04), (4.88, 0.12), (2.59, 0.06), (6.18, 0.06)),
    "Syrup-2": ((4.60, 0.15), (7.24, 0.39), (3.11, 0.19), (6.83, 0.04)),
    "Syrup-3": ((4.53, 0.31), (4.99, 1.69), (3.11, 0.76), (7.21, 0.76)),
}
TABLE_4_3 = {
    "Muscle 0": ((2.82, 0.55), (4.94, 1.60), (2.62, 1.16), (6.14, 0.95)),
    "Muscle 90": ((2.92, 2.92), (5.26, 4.77), (2.69, 0.91), (5.84, 0.67)),
    "Liver": ((1.37, 16.20), (3.96, 12.17), (3.05, 3.83), (4.56, 4.75)),
    "Kidney": ((1.97, 5.54), (1.92, 77.20), (2.78, 13.75), (5.36, 17.57)),
    "Fat": ((2.80, 1.05), (2.75, 10.14), (2.03, 6.64), (5.41, 1.70)),
}
SCALE = (1e12, 1e5, 1e12, 1e5)


def schema_table(sample_ids, estimates: dict[str, np.ndarray], truth: dict[str, np.ndarray] | None = None,
                 rel_se: float = 0.002, length: float = 0.05, diameter: float = 0.0254, n_elements: int = 10,
                 extra: dict | None = None) -> pd.DataFrame:
    """A table in the documented schema from estimated (and true) properties."""
    area = math.pi * diameter ** 2 / 4.0
    to_param = {"E_sigma": area / (length / n_elements), "eta_sigma": area / (length / n_elements),
                "E_tau": math.pi * diameter, "eta_tau": math.pi * diameter}
    n = len(sample_ids)
    df = pd.DataFrame({"sample_id": list(sample_ids)})
    for key, values in (extra or {}).items():
        df[key] = values
    df["replicate"] = np.nan
    df["replicates"] = "averaged"
    df["n_replicates"] = 1
    for prop, par in zip(PROPS, PARAMS):
        if prop not in estimates:
            continue
        value = np.asarray(estimates[prop], dtype=float)
        df[par] = value * to_param[prop]
        df[f"{par}_se"] = np.abs(df[par]) * rel_se
    for prop in PROPS:
        if prop not in estimates:
            continue
        value = np.asarray(estimates[prop], dtype=float)
        se = np.abs(value) * rel_se
        df[prop] = value
        df[f"{prop}_se"] = se
        df[f"{prop}_ci_low"] = value - 1.96 * se
        df[f"{prop}_ci_high"] = value + 1.96 * se
    df["nrmse"] = 0.03
    df["success"] = True
    df["warnings"] = ""
    df["error"] = ""
    for prop, values in (truth or {}).items():
        df[f"true_{prop}"] = values
    assert len(df) == n
    return df


def grouped_table(spec: dict, n_per_group: int, *, seed: int = 0, rel_se: float = 0.002,
                  by: str = "material") -> pd.DataFrame:
    """Samples of each group of a Table 4.2/4.3-like ``spec`` (see module docstring)."""
    rng = np.random.default_rng(seed)
    ids, labels = [], []
    truth = {p: [] for p in PROPS}
    for group, columns in spec.items():
        for i in range(n_per_group):
            ids.append(f"{group}-{i + 1}")
            labels.append(group)
            for prop, (mean, sd_pct), scale in zip(PROPS, columns, SCALE):
                truth[prop].append(mean * scale * (1.0 + sd_pct / 100.0 * rng.standard_normal()))
    truth = {p: np.abs(np.array(v)) for p, v in truth.items()}
    estimates = {p: v * (1.0 + rel_se * rng.standard_normal(v.size)) for p, v in truth.items()}
    return schema_table(ids, estimates, truth, rel_se, extra={by: labels})


def mark_failed(df: pd.DataFrame, rows, message: str = "solver failed: not converged") -> pd.DataFrame:
    """Rows turned into failed fits: error text, no properties."""
    df = df.copy()
    idx = df.index[list(rows)]
    df.loc[idx, "error"] = message
    df.loc[idx, "success"] = False
    for prop in PROPS:
        if prop in df.columns:
            df.loc[idx, prop] = np.nan
    return df
