"""The parts of result.json that say how far to trust the numbers: the information gate and
the profile-likelihood intervals (:mod:`mbus_framework.estimation.gate`,
:mod:`mbus_framework.estimation.profile`)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from mbus_framework.estimation.gate import information_gate
from mbus_framework.estimation.profile import compare, profile_intervals

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.estimation.problem import FitProblem, FitResult


def gate_warnings(result: dict[str, Any], problem: "FitProblem", fit: "FitResult", min_explained: float,
                  precise: float = 0.05) -> list[str]:
    """Adds ``fit.information`` to ``result``; one warning naming every parameter when the
    record holds too little response to trust any of them (not when the fit itself shows the
    response: every relative SE <= ``precise`` at a high signal-to-noise)."""
    rse = (result.get("uncertainty") or {}).get("relative_standard_errors")
    gate = information_gate(problem.y, fit.residuals, problem.u, min_explained,
                            relative_standard_errors=None if rse is None else list(rse.values()), precise=precise)
    result["fit"]["information"] = gate
    result["fit"]["reliable"] = gate["reliable"]
    if gate["reliable"]:
        return []
    names = [n for n, f in zip(fit.names, fit.free if fit.free is not None else [True] * len(fit.names)) if f]
    return [f"the record holds too little response to the input ({gate['reason']}; signal-to-noise "
            f"{gate['signal_to_noise']:.2g}): {_join(names)} are not reliable, whatever their standard errors say"]


def profile_warnings(result: dict[str, Any], problem: "FitProblem", fit: "FitResult", model, options) -> list[str]:
    """Adds profile-likelihood intervals of the parameters (and of the properties that depend
    on one parameter only) to ``result["uncertainty"]``; warns where they disagree with the
    linearised ones."""
    unc = result.get("uncertainty")
    if not unc or not options.profile:
        return []
    profiles = profile_intervals(problem, fit.theta, fit.cost, unc["relative_standard_errors"], options.level)
    unc["profile_level"] = options.level
    unc["profile_ci"] = {n: [p.lower, p.upper] for n, p in profiles.items()}
    unc["profile_points"] = {n: p.points for n, p in profiles.items()}
    flagged = compare(profiles, unc["ci95"], options.profile_tolerance) if abs(options.level - 0.95) < 1e-12 else []
    unc["profile_disagrees"] = {n: n in flagged for n in profiles}
    unc["property_profile_ci"] = _property_intervals(model, fit.theta[: problem.n_model], problem, profiles)
    out = []
    for name in flagged:
        lo, hi = unc["profile_ci"][name]
        shown = f"[{_fmt(lo)}, {_fmt(hi)}]"
        lin = unc["ci95"][name]
        out.append(f"the profile-likelihood interval of {name} {shown} differs from its linearised interval "
                   f"[{lin[0]:.4g}, {lin[1]:.4g}]: the cost is not quadratic there; report the profile interval")
    return out


def _property_intervals(model, theta_model: np.ndarray, problem: "FitProblem", profiles) -> dict[str, list]:
    """Each property that depends on exactly one profiled parameter, through its interval's ends."""
    base = model.to_properties(theta_model)
    out = {}
    for name in base:
        moved = []
        for i, pname in enumerate(problem.names[: problem.n_model]):
            bumped = theta_model.copy()
            bumped[i] *= 1.001
            if model.to_properties(bumped)[name] != base[name]:
                moved.append(pname)
        if len(moved) == 1 and moved[0] in profiles:
            i = problem.names.index(moved[0])
            ends = []
            for v in (profiles[moved[0]].lower, profiles[moved[0]].upper):
                if v is None:
                    ends.append(None)
                    continue
                th = theta_model.copy()
                th[i] = v
                ends.append(float(model.to_properties(th)[name]))
            if None not in ends:
                ends = sorted(ends)
            out[name] = ends
    return out


def _fmt(v) -> str:
    return "unbounded" if v is None else f"{v:.4g}"


def _join(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
