"""Rebuild the figures' arrays of a finished run folder from what it saved.

The folder holds the validated config, the record (measurement.csv), the estimates
(result.json) and the trace (trace.csv); the prediction is one simulation at the estimate
through the same compensator and nuisance settings as the fit.
"""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from mbus_framework.errors import MbusError
from mbus_framework.interfaces.backend import check_record
from mbus_framework.pipeline.figures import FitData


def read_trace(path: Path) -> list[dict[str, Any]]:
    """trace.csv -> [{'iteration', 'stage', 'cost', 'theta'}] (empty when there is none)."""
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    return [{"iteration": int(r[0]), "stage": r[1], "cost": float(r[2]), "theta": [float(v) for v in r[3:]]}
            for r in rows[1:] if r]


def fit_data_from_run(run_dir: Path, document: dict[str, Any]) -> FitData | None:
    """The run's FitData, or None when its config or record can no longer be used (a missing
    calibration file, a plugin that is not installed here)."""
    from mbus_framework.pipeline.reduction import reduce_record
    from mbus_framework.pipeline.run import designed_waveform, load_components, make_problem

    try:
        c = load_components(run_dir / "config.yaml")
        data = np.loadtxt(run_dir / "measurement.csv", delimiter=",", skiprows=1, ndmin=2)
        m = check_record(run_dir / "measurement.csv", data[:, 0], data[:, 1], data[:, 2])
        m, _ = reduce_record(m, c.config.estimation, str(run_dir / "config.yaml"))  # the part that was fitted
        problem = make_problem(c, c.compensator.apply(m))
        theta = np.array([document["parameters"][n] for n in problem.names], dtype=float)
        yhat = problem.predict(theta)
    except (MbusError, OSError, KeyError, ValueError):
        return None
    return FitData(problem.t, problem.u, problem.y, yhat, problem.names, read_trace(run_dir / "trace.csv"),
                   designed_waveform(c), document.get("title") or str(document.get("config") or ""),
                   document.get("dispersion"), document.get("record_units") or {})
