"""Local output-error least squares in the time domain (Levenberg-Marquardt, exact Jacobian).

Minimises 1/2 ||F (y - yhat(theta))||^2 (F an optional band-limiting filter of a continuation
stage) with ``scipy.optimize.least_squares(method="lm")`` (MINPACK) in unconstrained
coordinates z of the free parameters: z = ln theta for log-scale parameters (positivity and
scaling for free; a step may move a parameter at most e^23 ~ 1e10 from its start) and
z = theta / typical for the others (a delay), clipped to the problem's bounds. The Jacobian is
exact, d yhat / d z = (d yhat / d theta) (d theta / d z), from the forward-sensitivity system
of :mod:`mbus_framework.engine.simulation`; ``jacobian="finite_difference"`` uses SciPy's
2-point differences instead. Used by the ``scipy_lm`` solver and by profile likelihoods.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import least_squares

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.estimation.exploration import BandFilter
    from mbus_framework.estimation.problem import FitProblem

LOG_RANGE = 23.0  # a log-parameter may move at most e^23 ~ 1e10 from its start
STOP_SE = 0.05  # a final solve stops when its minimum is within this many standard errors ...
STOP_STEPS = 2  # ... at this many successive iterations


class _Settled(Exception):
    """Raised from the Jacobian callback when a final solve is statistically at its minimum."""

    def __init__(self, z: np.ndarray, cost: float):
        super().__init__("settled")
        self.z, self.cost = z, cost


def settled(Jz: np.ndarray, r: np.ndarray, fraction: float) -> bool:
    """True when the Gauss-Newton minimum of the linearised model is within ``fraction`` standard
    errors of the current point, in every direction at once.

    The Gauss-Newton step d solves J d ~ -r; its length in the Fisher metric,
    m = sqrt(d^T J^T J d) / sigma = ||U^T r|| / sigma (J = U S V^T, singular values below 1e-12
    of the largest dropped), bounds every parameter's move: |d_i| <= m SE_i, with
    SE_i = sigma sqrt([(J^T J)^-1]_ii) and sigma^2 = ||r||^2 / (N - p), the noise level the
    residual itself shows (as the reported intervals use it)."""
    n, k = Jz.shape
    if n <= k:
        return False
    u, sv, _ = np.linalg.svd(Jz, full_matrices=False)
    if not sv.size or not sv[0] > 0:
        return False
    proj = u[:, sv > 1e-12 * sv[0]].T @ r
    sigma2 = float(r @ r) / (n - k)
    return bool(sigma2 > 0 and float(proj @ proj) < fraction**2 * sigma2)


@dataclass
class LocalResult:
    """Outcome of one local least-squares solve."""

    theta: np.ndarray
    cost: float
    nfev: int
    njev: int
    status: int
    message: str
    iterations: int
    trace: list[dict] = field(default_factory=list)


class Coordinates:
    """Unconstrained coordinates z of the free parameters (see the module docstring)."""

    def __init__(self, problem: "FitProblem", theta0: np.ndarray):
        self.problem, self.theta0 = problem, np.asarray(theta0, dtype=float)
        params = [p for p, f in zip(problem.parameters, problem.free) if f]
        self.log = np.array([p.log_scale for p in params], dtype=bool)
        self.unit = np.array([p.typical if p.typical > 0 else 1.0 for p in params])
        start = self.theta0[problem.free]
        lo, hi = problem.lower[problem.free], problem.upper[problem.free]
        with np.errstate(divide="ignore", invalid="ignore"):
            self.z0 = np.where(self.log, np.log(np.maximum(start, 1e-300)), start / self.unit)
            zlo = np.where(self.log, np.log(lo), lo / self.unit)
            zhi = np.where(self.log, np.log(hi), hi / self.unit)
        self.zlo = np.where(self.log, np.maximum(zlo, self.z0 - LOG_RANGE), zlo)
        self.zhi = np.where(self.log, np.minimum(zhi, self.z0 + LOG_RANGE), zhi)

    def theta(self, z: np.ndarray) -> np.ndarray:
        z = np.clip(z, self.zlo, self.zhi)
        free_values = np.where(self.log, np.exp(np.where(self.log, z, 0.0)), z * self.unit)
        return self.problem.full(free_values, self.theta0)

    def dtheta_dz(self, theta: np.ndarray) -> np.ndarray:
        return np.where(self.log, theta[self.problem.free], self.unit)


def lm_fit(problem: "FitProblem", theta0: np.ndarray, band: "BandFilter | None", max_nfev: int, final: bool,
           jacobian: str = "exact", xtol: float = 1e-10, ftol: float = 1e-12,
           stop_se: float | None = STOP_SE) -> "LocalResult":
    """One local Levenberg-Marquardt solve from ``theta0``; final solves use ``xtol``/``ftol``,
    continuation stages looser tolerances (1e-6, 1e-8). Records a trace per Jacobian.

    A final solve (exact Jacobian, full band) also stops when, at ``STOP_STEPS`` successive
    iterations, the Gauss-Newton minimum is within ``stop_se`` standard errors (:func:`settled`):
    further iterations cannot move any estimate by anything its interval can show (MINPACK's
    ``xtol``/``ftol`` otherwise go on to round-off). ``stop_se=None`` turns this off."""
    free = problem.free
    coords = Coordinates(problem, theta0)
    y = band(problem.y) if band else problem.y
    scale = float(np.sqrt(np.mean(problem.y**2))) or 1.0
    trace: list[dict] = []
    settle = final and band is None and jacobian == "exact" and stop_se is not None and stop_se > 0
    last = {"small": 0}

    def residual(z):
        with np.errstate(over="ignore", invalid="ignore"):
            yhat = problem.predict(coords.theta(z))
        r = (band(yhat) if band else yhat) - y
        if not np.all(np.isfinite(r)):
            return np.full_like(y, 1e6 * scale)
        return r

    def jac(z):
        theta = coords.theta(z)
        with np.errstate(over="ignore", invalid="ignore"):
            yhat, J = problem.predict_with_jacobian(theta)
        Jz = J[:, free] * coords.dtheta_dz(theta)
        if band:
            yhat, Jz = band(yhat), band(Jz)
        with np.errstate(over="ignore", invalid="ignore"):
            r = yhat - y
            trace.append({"iteration": len(trace), "cost": 0.5 * float(r @ r), "theta": theta.tolist()})
        if not np.all(np.isfinite(Jz)):
            return np.zeros_like(Jz)
        if settle and np.all(np.isfinite(r)):
            last["small"] = last["small"] + 1 if settled(Jz, r, stop_se) else 0
            if last["small"] >= STOP_STEPS:
                raise _Settled(np.array(z, dtype=float), 0.5 * float(r @ r))
        return Jz

    tol = dict(xtol=xtol, ftol=ftol) if final else dict(xtol=1e-6, ftol=1e-8)
    counts = {"nfev": 0}

    def counted(z):
        counts["nfev"] += 1
        return residual(z)

    try:
        res = least_squares(counted, coords.z0, jac=jac if jacobian == "exact" else "2-point", method="lm",
                            max_nfev=max_nfev, x_scale=1.0, **tol)
    except _Settled as done:
        return LocalResult(theta=coords.theta(done.z), cost=done.cost, nfev=counts["nfev"], njev=len(trace),
                           status=2, message=f"the Gauss-Newton minimum within {stop_se:g} standard errors at "
                           f"{STOP_STEPS} successive iterations", iterations=len(trace), trace=trace)
    njev = int(res.njev or 0) if res.njev is not None else 0
    return LocalResult(theta=coords.theta(res.x), cost=float(res.cost), nfev=int(res.nfev), njev=njev,
                       status=int(res.status), message=str(res.message), iterations=njev, trace=trace)
