"""The ``result.json`` document of a run (schema documented in the README)."""
from __future__ import annotations

import datetime as _dt
from typing import TYPE_CHECKING, Any

import numpy as np

from . import __version__
from .uncertainty import from_jacobian, property_covariance

if TYPE_CHECKING:  # pragma: no cover
    from .backend import Measurement
    from .excitation import Waveform
    from .run import Components
    from .solver import FitProblem, FitResult


def build_result(c: "Components", m: "Measurement", problem: "FitProblem", fit: "FitResult", waveform: "Waveform") -> dict[str, Any]:
    model = c.model
    theta = fit.theta
    props = model.to_properties(theta)
    r = fit.residuals
    y = problem.y
    mse = float(np.mean(r**2))
    rms_y = float(np.sqrt(np.mean(y**2))) or 1.0
    result: dict[str, Any] = {
        "mbus_version": __version__,
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "config": c.source,
        "title": c.config.title,
        "model": {
            "name": c.config.model.name,
            "options": model.options.model_dump(mode="json"),
            "n_states": int(model.state_space(theta).A.shape[0]),
        },
        "parameters": fit.parameters,
        "parameter_units": {p.name: p.unit for p in model.parameters},
        "properties": props,
        "property_units": {p.name: p.unit for p in model.properties},
        "fixed": dict(problem.fixed),
        "fit": {
            "mse": mse,
            "nrmse": float(np.sqrt(mse)) / rms_y,
            "n_samples": int(len(y)),
            "dt_s": problem.dt,
        },
        "solver": {
            "name": c.config.solver.name,
            "success": bool(fit.success),
            "status": int(fit.status),
            "message": fit.message,
            "nfev": int(fit.nfev),
            "njev": int(fit.njev),
            "iterations": int(fit.iterations),
            "cost": float(fit.cost),
            "wall_time_s": float(fit.wall_time_s),
            "extras": fit.extras,
        },
        "strategy": fit.strategy,
        "excitation": {"name": c.config.excitation.name, **waveform.info},
        "files": {"measurement": "measurement.csv", "measurement_meta": "measurement.json"},
    }
    if fit.jacobian is not None and fit.free is not None and fit.free.any():
        names = [n for n, f in zip(fit.names, fit.free) if f]
        unc = from_jacobian(names, fit.jacobian, fit.cost)
        free_values = theta[fit.free]
        ci = unc.intervals(free_values)
        pnames, pvalues, pcov = property_covariance(model.to_properties, theta, fit.free, unc.covariance)
        pse = np.sqrt(np.clip(np.diag(pcov), 0, None))
        q = ci[:, 1] - free_values  # t-quantile * SE, same for properties
        qfac = (q / unc.standard_errors)[0] if unc.standard_errors[0] > 0 else 1.96
        result["uncertainty"] = {
            "method": "linearised: s^2 (J^T J)^-1, s^2 = 2 cost / (N - p)",
            "residual_std": unc.residual_std,
            "standard_errors": dict(zip(names, unc.standard_errors)),
            "relative_standard_errors": dict(zip(names, unc.relative_standard_errors(free_values))),
            "ci95": {n: list(b) for n, b in zip(names, ci)},
            "correlation": {"names": names, "matrix": unc.correlation.tolist()},
            "property_standard_errors": dict(zip(pnames, pse)),
            "property_ci95": {n: [v - qfac * s, v + qfac * s] for n, v, s in zip(pnames, pvalues, pse)},
        }
    if m.truth:
        truth = {k: float(v) for k, v in m.truth.items()}
        tprops = model.to_properties(np.array([truth[n] for n in model.parameter_names]))
        result["truth"] = truth
        result["truth_properties"] = tprops
        result["error_percent"] = {n: 100.0 * (fit.parameters[n] / truth[n] - 1.0) for n in truth if truth[n] != 0}
    elif m.meta.get("true_properties"):
        result["truth_properties"] = m.meta["true_properties"]
    return result
