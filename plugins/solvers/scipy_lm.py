"""``scipy_lm`` solver: Levenberg-Marquardt output-error fit with a global strategy.

Local solves are ``scipy.optimize.least_squares(method="lm")`` (MINPACK) on the residual
r = F(y - yhat(theta)), F an optional band-limiting filter of the continuation, in
log-parameters phi = ln(theta) (positivity and scaling for free). The Jacobian is exact,
d yhat / d phi = (d yhat / d theta) theta, from the forward-sensitivity system
(:mod:`mbus_framework.engine.simulation`); ``jacobian: finite_difference`` switches to SciPy's
2-point differences for comparison. The global strategy is :mod:`mbus_framework.estimation.strategy`.
"""
from __future__ import annotations

import time
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import least_squares

from mbus_framework.interfaces.hookspecs import SolverSpec, hookimpl
from mbus_framework.estimation.problem import FitProblem, FitResult, Progress, Solver
from mbus_framework.estimation.strategy import BandFilter, LocalResult, StrategyOptions, search

LOG_RANGE = 23.0  # a log-parameter may move at most e^23 ~ 1e10 from its start


class ScipyLMOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    jacobian: Literal["exact", "finite_difference"] = Field("exact", description="Jacobian used by LM")
    xtol: float = Field(1e-10, gt=0, description="final-solve relative step tolerance")
    ftol: float = Field(1e-12, gt=0, description="final-solve relative cost tolerance")
    strategy: StrategyOptions = Field(default_factory=StrategyOptions)


class ScipyLM(Solver):
    """SciPy Levenberg-Marquardt with time-scale alignment, band continuation and multi-start."""

    Options = ScipyLMOptions
    summary = "SciPy Levenberg-Marquardt (exact Jacobian) with a global strategy"

    def solve(self, problem: FitProblem, progress: Progress | None = None) -> FitResult:
        t0 = time.perf_counter()
        best, report, nfev, njev = search(problem, self._local_fit, self.options.strategy, progress)
        return FitResult.at_estimate(
            problem,
            best,
            nfev=nfev,
            njev=njev,
            wall_time_s=time.perf_counter() - t0,
            strategy=report.as_dict(),
            extras={"method": "lm", "jacobian": self.options.jacobian},
        )

    def _local_fit(
        self, problem: FitProblem, theta0: np.ndarray, band: BandFilter | None, max_nfev: int, final: bool
    ) -> LocalResult:
        free = problem.free
        coords = Coordinates(problem, theta0)
        y = band(problem.y) if band else problem.y
        scale = float(np.sqrt(np.mean(problem.y**2))) or 1.0
        trace: list[dict] = []

        def residual(z):
            with np.errstate(over="ignore", invalid="ignore"):
                yhat = problem.predict(coords.theta(z))
            r = (band(yhat) if band else yhat) - y
            if not np.all(np.isfinite(r)):
                return np.full_like(y, 1e6 * scale)
            return r

        def jacobian(z):
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
            return Jz

        jac = jacobian if self.options.jacobian == "exact" else "2-point"
        tol = dict(xtol=self.options.xtol, ftol=self.options.ftol) if final else dict(xtol=1e-6, ftol=1e-8)
        res = least_squares(residual, coords.z0, jac=jac, method="lm", max_nfev=max_nfev, x_scale=1.0, **tol)
        theta = coords.theta(res.x)
        njev = int(res.njev or 0) if res.njev is not None else 0
        return LocalResult(
            theta=theta,
            cost=float(res.cost),
            nfev=int(res.nfev),
            njev=njev,
            status=int(res.status),
            message=str(res.message),
            iterations=njev,
            trace=trace,
        )


class Coordinates:
    """Unconstrained coordinates z of the free parameters.

    log-scale parameters: z = ln(theta), moving at most e^23 from the start;
    linear ones (e.g. a delay): z = theta / typical. Values are clipped to the bounds.
    """

    def __init__(self, problem: FitProblem, theta0: np.ndarray):
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


@hookimpl
def mbus_solvers():
    return [SolverSpec("scipy_lm", ScipyLM, ScipyLM.summary)]
