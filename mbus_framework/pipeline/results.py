"""The ``result.json`` document of a run (schema documented in docs/results.md)."""
from __future__ import annotations

import datetime as _dt
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import special

from mbus_framework import __version__
from mbus_framework.estimation.combinations import extreme_combinations
from mbus_framework.estimation.nuisance import DELAY, GAIN
from mbus_framework.estimation.strategy import at_box_edge, residual_autocorrelation
from mbus_framework.estimation.uncertainty import confidence_intervals, from_jacobian, property_covariance
from mbus_framework.pipeline.confidence import gate_warnings, profile_warnings
from mbus_framework.pipeline.dispersion import dispersion_section
from mbus_framework.pipeline.hints import record_hints
from mbus_framework.pipeline.units import apply_units, record_units

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.interfaces.backend import Measurement
    from mbus_framework.interfaces.excitation import Waveform
    from mbus_framework.pipeline.components import Components
    from mbus_framework.estimation.problem import FitProblem, FitResult


def build_result(
    c: "Components",
    m: "Measurement",
    problem: "FitProblem",
    fit: "FitResult",
    waveform: "Waveform | None",
    compensation: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The result.json document; ``compensation`` is what the compensator reports."""
    noise_filter = c.compensator.noise_filter()
    comp_sigma = (compensation or {}).get("noise_std")
    model = c.model
    theta = fit.theta
    n_model = problem.n_model
    props = model.to_properties(theta[:n_model])
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
            "n_states": int(model.n_states),
        },
        "parameters": fit.parameters,
        "parameter_units": {p.name: p.unit for p in problem.parameters},
        "properties": props,
        "property_units": {p.name: p.unit for p in model.properties},
        "derived_properties": _derived(model, theta[:n_model]),
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
        "excitation": {"name": c.config.excitation.name if c.config.excitation else "recorded",
                       **(waveform.info if waveform is not None else {})},
        "files": {"measurement": "measurement.csv", "measurement_meta": "measurement.json"},
        "record_units": record_units(m.meta, compensation),
    }
    dispersion_cov = (None, None)  # (covariance, free mask) of the model parameters, when known
    if fit.jacobian is not None and fit.free is not None and fit.free.any():
        names = [n for n, f in zip(fit.names, fit.free) if f]
        unc = from_jacobian(
            names,
            fit.jacobian,
            fit.cost,
            scale=comp_sigma**2 if (noise_filter is not None and comp_sigma) else None,
            noise_filter=noise_filter,
            dt=problem.dt,
        )
        free_values = theta[fit.free]
        positive = [p.log_scale for p, f in zip(problem.parameters, fit.free) if f]
        ci = unc.intervals(free_values, positive=positive)
        model_free = fit.free[:n_model]
        in_model = np.flatnonzero(fit.free) < n_model  # free entries that are model parameters
        cov_model = unc.covariance[np.ix_(in_model, in_model)]
        pnames, pvalues, pcov = property_covariance(model.to_properties, theta[:n_model], model_free, cov_model)
        pse = np.sqrt(np.clip(np.diag(pcov), 0, None))
        qfac = float(special.stdtrit(unc.dof, 0.975))  # the same Student-t quantile as the parameters' CIs
        ppos = {p.name: p.positive for p in model.properties}
        pci = confidence_intervals(pvalues, pse, qfac, [ppos.get(n, False) for n in pnames])
        # a property that moves with no free parameter (set by model.fixed) is fixed, not [v, v]
        held = {n for n, s in zip(pnames, pse) if s == 0.0} if problem.fixed else set()
        if held:
            result["fixed_properties"] = [n for n in pnames if n in held]
        dispersion_cov = (cov_model, model_free)
        result["uncertainty"] = {
            "method": (
                "linearised: s^2 (J^T J)^-1, s^2 = 2 cost / (N - p)"
                if noise_filter is None
                else "linearised sandwich for compensated (filtered) noise: s^2 A (F^T J)^T (F^T J) A, A = (J^T J)^-1"
            ),
            "residual_std": unc.residual_std,
            "condition": unc.condition,
            "standard_errors": dict(zip(names, unc.standard_errors)),
            "relative_standard_errors": dict(zip(names, unc.relative_standard_errors(free_values))),
            "ci95": {n: list(b) for n, b in zip(names, ci)},
            "correlation": {"names": names, "matrix": unc.correlation.tolist()},
            "property_standard_errors": {n: s for n, s in zip(pnames, pse) if n not in held},
            "property_ci95": {n: [float(lo), float(hi)] for n, (lo, hi) in zip(pnames, pci) if n not in held},
        }
    cov, free_model = dispersion_cov
    section = dispersion_section(model, theta[:n_model], problem.u, problem.dt, free_model, cov)
    if section is not None:
        result["dispersion"] = section
    if m.truth:
        truth = {k: float(v) for k, v in m.truth.items()}
        tprops = model.to_properties(np.array([truth[n] for n in model.parameter_names]))
        if problem.nuisance.active:
            truth[GAIN] = float(m.meta.get("true_input_gain", 1.0))
            truth[DELAY] = float(m.meta.get("true_delay_s", 0.0))
        result["truth"] = truth
        result["truth_properties"] = tprops
        result["error_percent"] = {n: 100.0 * (fit.parameters[n] / truth[n] - 1.0) for n in truth if truth[n] != 0}
        if "uncertainty" in result and m.meta.get("noise_std"):
            crb = cramer_rao(
                problem, np.array([truth[n] for n in problem.names]), float(m.meta["noise_std"]), noise_filter
            )
            result["uncertainty"]["cramer_rao"] = crb
    elif m.meta.get("true_properties"):
        result["truth_properties"] = m.meta["true_properties"]
    if compensation:
        result["compensation"] = compensation
    whiteness = residual_autocorrelation(fit.residuals)
    result["fit"]["residual_autocorrelation"] = whiteness
    measured = measurement_warnings(m) + record_hints(m)  # hints: wrong time unit, swapped channels
    result["warnings"] = measured + gate_warnings(result, problem, fit, c.config.identifiability.min_explained_variance,
                                            c.config.identifiability.precise_relative_se)
    result["warnings"] += identifiability_warnings(result, c.config.identifiability, fit)
    nuis = problem.nuisance
    apply_units(result, m.meta, nuis.estimate_gain or nuis.gain != 1.0, GAIN)
    result["warnings"] += profile_warnings(result, problem, fit, model, c.config.uncertainty)
    if noise_filter is None and whiteness > c.config.identifiability.max_residual_autocorrelation:
        result["warnings"].insert(
            len(measured) + int(not result["fit"]["reliable"]),
            f"the residuals are not white (mean |autocorrelation| {whiteness:.2f}): the model does not explain "
            f"the data (model mismatch, transducer dynamics or a local minimum); the estimates are biased",
        )
    return result


MEASUREMENT_WARNING = "measurement: "


def measurement_warnings(m: "Measurement") -> list[str]:
    """What the backend flagged about the record (a partial lab acquisition, clipping, ...),
    each prefixed ``measurement: ``."""
    found = m.meta.get("warnings")
    return [MEASUREMENT_WARNING + str(w) for w in found] if isinstance(found, list) else []


def _derived(model, theta: np.ndarray) -> dict[str, float]:
    """Non-invertible extras a model offers (relaxation times [s], unrelaxed moduli [Pa])."""
    derived = getattr(model, "derived_properties", None)
    return dict(derived(theta)) if callable(derived) else {}


def cramer_rao(problem: "FitProblem", theta_true: np.ndarray, noise_std: float, noise_filter=None) -> dict[str, float]:
    """Standard errors at the truth with the known noise std: sqrt(diag(sigma^2 (J^T J)^-1)),
    the Cramer-Rao bound; with a compensation filter, the sandwich of this estimator."""
    _, J = problem.predict_with_jacobian(theta_true)
    names = [n for n, f in zip(problem.names, problem.free) if f]
    unc = from_jacobian(names, J[:, problem.free], 0.0, noise_std**2, noise_filter, problem.dt)
    return dict(zip(names, map(float, unc.standard_errors)))


def identifiability_warnings(result: dict[str, Any], limits, fit: "FitResult") -> list[str]:
    """Plain-language warnings: unconverged solver, unconfirmed minimum, correlated groups that
    are also imprecise, large standard errors (rules in docs/estimation.md)."""
    out: list[str] = []
    if not fit.success:
        out.append(f"the solver did not report convergence ({fit.message}); treat the estimates with care")
    strategy = result.get("strategy") or {}
    if strategy and not strategy.get("accepted", True):
        out.append(
            "the global minimum is not confirmed: "
            + str((strategy.get("verdict") or {}).get("reason") or "no start left a residual consistent with the noise")
            + "; the estimates may be a local minimum (or the model does not describe the data)"
        )
    if strategy.get("stopped_by_budget"):
        out.append(f"the search was stopped: {strategy['stopped_by_budget']}")
    edge = at_box_edge(strategy, result["parameters"])
    if edge:
        out.append(
            f"{_join(edge)} ended on the edge of the search region (the plausible material range, widened "
            f"where needed): the data do not pin {'it' if len(edge) == 1 else 'them'} down"
        )
    unc = result.get("uncertainty")
    if not unc:
        return out
    if unc.get("condition", 1.0) < 1e-8:
        out.append(
            f"the Jacobian is nearly rank deficient (singular value ratio {unc['condition']:.1e}): some "
            f"combination of parameters is not determined by this record"
        )
    names = unc["correlation"]["names"]
    corr = np.asarray(unc["correlation"]["matrix"])
    unc["correlated_groups"] = groups = correlation_report(result, names, corr, limits)
    out += [g["warning"] for g in groups if g["warning"]]
    bad = {n: r for n, r in unc["relative_standard_errors"].items() if not np.isfinite(r) or r > limits.max_relative_se}
    if bad:
        listed = ", ".join(f"{n} ({100 * r:.3g} %)" if np.isfinite(r) else f"{n} (undefined)" for n, r in bad.items())
        out.append(
            f"practically unidentifiable, standard error above {100 * limits.max_relative_se:.0f} % of the "
            f"estimate: {listed}; do not report these values"
        )
    return out


def correlation_report(result: dict[str, Any], names: list[str], corr: np.ndarray, limits) -> list[dict[str, Any]]:
    """Each group of parameters correlated beyond ``limits.max_correlation``, with the power
    products of its most strongly correlated pair that the record determines best and worst
    (:mod:`mbus_framework.estimation.combinations`).

    Correlation alone is never a warning: the group's ``warning`` is set only when one of its
    members has a relative standard error above ``limits.precise_relative_se``, and then
    names what the record does determine."""
    unc = result["uncertainty"]
    rse = unc["relative_standard_errors"]
    out = []
    for group, worst in correlated_groups(names, corr, limits.max_correlation):
        idx = [names.index(n) for n in group]
        i, j = max(((a, b) for a in idx for b in idx if a < b), key=lambda ab: abs(corr[ab]))
        pair = [names[i], names[j]]  # the most strongly correlated pair: a readable combination
        se = np.array([unc["standard_errors"][n] for n in pair])
        values = np.array([result["parameters"][n] for n in pair])
        extremes = extreme_combinations(pair, values, corr[np.ix_([i, j], [i, j])] * np.outer(se, se))
        largest = max((rse[n] if np.isfinite(rse[n]) else np.inf) for n in group)
        entry: dict[str, Any] = {"parameters": group, "max_correlation": worst, "max_relative_se": largest,
                                 "best": extremes[0].as_dict() if extremes else None,
                                 "worst": extremes[1].as_dict() if extremes else None, "warning": None}
        if largest > limits.precise_relative_se:
            shown = f"{100 * largest:.3g} %" if np.isfinite(largest) else "undefined"
            what = (f"; the record determines {extremes[0].expression} to {_pct(extremes[0].relative_se)}"
                    f" and {extremes[1].expression} only to {_pct(extremes[1].relative_se)}") if extremes else ""
            entry["warning"] = (
                f"{_join(group)} are correlated (|r| up to {worst:.3f} > {limits.max_correlation}) and imprecise "
                f"(relative standard error up to {shown} > {100 * limits.precise_relative_se:.3g} %){what}: "
                f"report that combination, not their individual values")
        out.append(entry)
    return out


def _pct(fraction: float) -> str:
    return f"{100 * fraction:.2g} %" if np.isfinite(fraction) else "an undefined precision"


def correlated_groups(names: list[str], corr: np.ndarray, threshold: float) -> list[tuple[list[str], float]]:
    """Connected groups of parameters linked by |correlation| > threshold, with the largest |r|."""
    n = len(names)
    parent = list(range(n))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(n):
        for j in range(i + 1, n):
            if abs(corr[i, j]) > threshold:
                parent[find(i)] = find(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    out = []
    for members in groups.values():
        if len(members) > 1:
            worst = max(abs(corr[i, j]) for i in members for j in members if i < j)
            out.append(([names[i] for i in members], float(worst)))
    return out


def _join(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
