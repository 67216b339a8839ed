"""The two ways of combining a sample's replicate records.

``average``: the records are averaged sample by sample before one fit (what the dissertation
did with its shots): u = mean_r u_r, y = mean_r y_r on the common time grid; the noise std of
the average is sigma / sqrt(R) for R independent records.

``fit``: each replicate is fitted; :func:`aggregate_replicates` then gives per sample the mean
of each quantity over its fitted replicates, the standard deviation between them (ddof 1) and
the standard error of the mean, SD / sqrt(n).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.interfaces.backend import Measurement

#: relative tolerance on the time step of records that are averaged
STEP_TOLERANCE = 1e-6


def average_records(records: Sequence[Measurement], names: Sequence[str], where: str) -> Measurement:
    """Sample-wise mean of ``records`` (equal length and time step); ``names`` label them in errors.

    The truth is kept when every record has the same one (replicates of one simulated medium).
    """
    if not records:
        raise DataError(f"{where}: no replicate records to average")
    first = records[0]
    for name, m in zip(names[1:], records[1:]):
        if len(m.t) != len(first.t):
            raise DataError(f"{where}: replicate {name} has {len(m.t)} samples but {names[0]} has {len(first.t)}; "
                            f"averaged replicates need records of equal length")
        if abs(m.dt - first.dt) > STEP_TOLERANCE * first.dt:
            raise DataError(f"{where}: replicate {name} has a time step of {m.dt:.6g} s but {names[0]} has "
                            f"{first.dt:.6g} s; averaged replicates need the same sampling")
    u = np.mean([np.asarray(m.u, float) for m in records], axis=0)
    y = np.mean([np.asarray(m.y, float) for m in records], axis=0)
    truths = [m.truth for m in records]
    truth = dict(first.truth) if first.truth and all(t == first.truth for t in truths) else None
    meta = {"averaged_replicates": list(names), "n_records": len(records)}
    true_props = [m.meta.get("true_properties") for m in records]
    if true_props[0] and all(p == true_props[0] for p in true_props):
        meta["true_properties"] = dict(true_props[0])
    return Measurement(np.asarray(first.t, float) - float(first.t[0]), u, y, truth=truth, meta=meta)


def aggregate_replicates(table, by: Sequence[str], quantities: Sequence[str]):
    """Per sample (``by`` columns): n_fitted, and for each quantity its mean, SD (ddof 1) and
    SE of the mean (SD / sqrt(n)) over the rows without an error. Returns a pandas DataFrame."""
    import pandas as pd

    ok = table[table["error"].isna()] if "error" in table else table
    present = [q for q in quantities if q in table.columns]
    rows = []
    for key, part in table.groupby(list(by), sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        good = ok.loc[ok.index.intersection(part.index)]
        row = dict(zip(by, key))
        row["n_replicates"] = len(part)
        row["n_fitted"] = len(good)
        for q in present:
            v = pd.to_numeric(good[q], errors="coerce").dropna().to_numpy(float)
            sd = float(np.std(v, ddof=1)) if v.size > 1 else float("nan")
            row[q] = float(np.mean(v)) if v.size else float("nan")
            row[f"{q}_sd"] = sd
            row[f"{q}_sem"] = sd / np.sqrt(v.size) if v.size > 1 else float("nan")
        rows.append(row)
    return pd.DataFrame(rows)
