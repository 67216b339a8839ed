"""Profile-likelihood intervals: what the data allow for one parameter, the others refitted.

For a free parameter theta_i the profile cost is S_p(v) = min over the other free parameters
of S(theta) with theta_i = v (S = 1/2 ||y - yhat||^2). With s^2 = 2 S_min / (N - p), the
level-(1 - alpha) profile interval is

    { v : 2 (S_p(v) - S_min) / s^2 <= F_{1, N-p}(1 - alpha) },

exact for a linear model and, unlike the linearised interval theta_i +- t SE_i, honest where
the cost is not quadratic (a bound that is far away on one side, a second valley, a parameter
the data barely see). Each side is found by stepping ln theta_i away from the estimate (steps
growing from the linearised SE) until the profile crosses the threshold, then by secant steps
on sqrt(S_p - S_min) - sqrt(threshold), which is nearly linear in the parameter. A side that
does not cross within ``max_ratio`` x/÷ of the estimate is unbounded (None).

Each profile point is a local fit (the run's Levenberg-Marquardt, warm-started from the
previous point) of the problem with theta_i fixed.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy import special

from mbus_framework.estimation.local import lm_fit
from mbus_framework.estimation.problem import FitProblem


@dataclass
class ProfileInterval:
    """One parameter's profile interval; None for an unbounded side. ``points``: (value, cost)."""

    name: str
    estimate: float
    lower: float | None
    upper: float | None
    points: list[tuple[float, float]] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"lower": self.lower, "upper": self.upper, "points": [list(p) for p in self.points]}


def threshold(cost_min: float, dof: int, level: float = 0.95) -> float:
    """Largest S_p - S_min inside the interval: s^2 F_{1,dof}(level) / 2, s^2 = 2 S_min / dof."""
    s2 = 2.0 * cost_min / max(dof, 1)
    return 0.5 * s2 * float(special.fdtri(1, max(dof, 1), level))  # F_{1,dof} quantile


def profile_intervals(problem: FitProblem, theta: np.ndarray, cost_min: float, relative_se: dict[str, float],
                      level: float = 0.95, max_ratio: float = 1e3, max_evaluations: int = 10,
                      max_nfev: int = 60) -> dict[str, ProfileInterval]:
    """Profile intervals of every free log-scale parameter (see the module docstring)."""
    theta = np.asarray(theta, dtype=float)
    dof = int(problem.y.size - problem.free.sum())
    limit = threshold(cost_min, dof, level)
    out = {}
    for i, p in enumerate(problem.parameters):
        if not problem.free[i] or not p.log_scale or theta[i] <= 0:
            continue
        step = float(np.clip(relative_se.get(p.name, 0.01), 1e-4, 1.0)) if np.isfinite(relative_se.get(p.name, 0.01)) else 1.0
        side_values = [_side(problem, theta, i, cost_min, limit, sign, step, max_ratio, max_evaluations, max_nfev)
                       for sign in (-1.0, 1.0)]
        (lo, pts_lo), (hi, pts_hi) = side_values
        points = sorted(pts_lo + [(float(theta[i]), float(cost_min))] + pts_hi)
        out[p.name] = ProfileInterval(p.name, float(theta[i]), lo, hi, points)
    return out


def _profile_cost(problem: FitProblem, theta: np.ndarray, i: int, value: float, max_nfev: int):
    """(S_p(value), the refitted vector) with theta_i held at ``value``."""
    fixed = dict(problem.fixed)
    fixed[problem.names[i]] = float(value)
    sub = dataclasses.replace(problem, fixed=fixed, initial=None)
    start = theta.copy()
    start[i] = value
    if not sub.free.any():
        r = sub.y - sub.predict(start)
        return 0.5 * float(r @ r), start
    res = lm_fit(sub, start, None, max_nfev, False)
    return float(res.cost), res.theta


def _side(problem, theta, i, cost_min, limit, sign, step, max_ratio, max_evaluations, max_nfev):
    """Walk ln theta_i in direction ``sign`` until the profile crosses cost_min + limit."""
    lo_b, hi_b = problem.lower[i], problem.upper[i]
    base = np.log(theta[i])
    points: list[tuple[float, float]] = []
    inside = (0.0, 0.0)  # (offset in ln theta_i, g = sqrt(excess) - sqrt(limit)) known inside
    g_in = -np.sqrt(limit)
    current = theta.copy()
    h = 2.0 * step
    for _ in range(max_evaluations):
        if abs(h) > np.log(max_ratio):
            h = np.log(max_ratio)
        value = float(np.exp(base + sign * h))
        if not (lo_b <= value <= hi_b):
            value = float(np.clip(value, lo_b, hi_b))
            h = abs(np.log(value) - base)
            if h == 0:
                return None, points
        cost, current = _profile_cost(problem, current, i, value, max_nfev)
        points.append((value, cost))
        g = np.sqrt(max(cost - cost_min, 0.0)) - np.sqrt(limit)
        if g >= 0:  # crossed: secant steps between the inside point and this one
            out_h, g_out = h, g
            in_h = inside[0]
            for _ in range(3):
                cand = in_h + (out_h - in_h) * (-g_in) / (g_out - g_in)
                v = float(np.exp(base + sign * cand))
                c, _ = _profile_cost(problem, theta, i, v, max_nfev)
                points.append((v, c))
                gc = np.sqrt(max(c - cost_min, 0.0)) - np.sqrt(limit)
                if abs(gc) < 0.02 * np.sqrt(limit):
                    return v, points
                if gc < 0:
                    in_h, g_in = cand, gc
                else:
                    out_h, g_out = cand, gc
            return float(np.exp(base + sign * in_h + sign * (out_h - in_h) * (-g_in) / (g_out - g_in))), points
        inside, g_in = (h, g), g
        if h >= np.log(max_ratio) or value in (lo_b, hi_b):
            return None, points
        h *= 2.0
    return None, points


def compare(profile: dict[str, ProfileInterval], linear: dict[str, list[float]], tolerance: float = 0.25) -> list[str]:
    """Parameters whose profile interval differs from the linearised one by more than
    ``tolerance`` of the linearised half-width at either end, or is unbounded."""
    out = []
    for name, pi in profile.items():
        lin = linear.get(name)
        if lin is None:
            continue
        half = 0.5 * (lin[1] - lin[0])
        if pi.lower is None or pi.upper is None or half <= 0:
            out.append(name)
        elif abs(pi.lower - lin[0]) > tolerance * half or abs(pi.upper - lin[1]) > tolerance * half:
            out.append(name)
    return out
