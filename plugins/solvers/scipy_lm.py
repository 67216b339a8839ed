"""``scipy_lm`` solver: Levenberg-Marquardt output-error fit with a global strategy.

Local solves are ``scipy.optimize.least_squares(method="lm")`` (MINPACK) on the residual
r = F(y - yhat(theta)), F an optional band-limiting filter of the continuation, in
log-parameters phi = ln(theta) (positivity and scaling for free). The Jacobian is exact,
d yhat / d phi = (d yhat / d theta) theta, from the forward-sensitivity system
(:mod:`mbus_framework.simulation`); ``jacobian: finite_difference`` switches to SciPy's
2-point differences for comparison. The global strategy is :mod:`mbus_framework.strategy`.
"""
from __future__ import annotations

import time
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import least_squares

from mbus_framework.hookspecs import SolverSpec, hookimpl
from mbus_framework.solver import FitProblem, FitResult, Progress, Solver
from mbus_framework.strategy import BandFilter, LocalResult, StrategyOptions, search

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
        yhat, J = problem.predict_with_jacobian(best.theta)
        residuals = problem.y - yhat
        return FitResult(
            names=problem.names,
            theta=best.theta,
            success=best.status > 0,
            status=best.status,
            message=best.message,
            nfev=nfev,
            njev=njev,
            iterations=best.iterations,
            cost=0.5 * float(residuals @ residuals),
            wall_time_s=time.perf_counter() - t0,
            residuals=residuals,
            jacobian=J[:, problem.free],
            free=problem.free,
            trace=best.trace,
            strategy=report.as_dict(),
            extras={"method": "lm", "jacobian": self.options.jacobian},
        )

    def _local_fit(
        self, problem: FitProblem, theta0: np.ndarray, band: BandFilter | None, max_nfev: int, final: bool
    ) -> LocalResult:
        free = problem.free
        phi0 = np.log(theta0[free])
        lo_phi, hi_phi = phi0 - LOG_RANGE, phi0 + LOG_RANGE
        with np.errstate(divide="ignore"):
            lo_phi = np.maximum(lo_phi, np.log(problem.lower[free]))
            hi_phi = np.minimum(hi_phi, np.log(problem.upper[free]))
        y = band(problem.y) if band else problem.y
        scale = float(np.sqrt(np.mean(problem.y**2))) or 1.0
        trace: list[dict] = []

        def theta_of(phi):
            return problem.full(np.exp(np.clip(phi, lo_phi, hi_phi)), theta0)

        def residual(phi):
            with np.errstate(over="ignore", invalid="ignore"):
                yhat = problem.predict(theta_of(phi))
            r = (band(yhat) if band else yhat) - y
            if not np.all(np.isfinite(r)):
                return np.full_like(y, 1e6 * scale)
            return r

        def jacobian(phi):
            theta = theta_of(phi)
            with np.errstate(over="ignore", invalid="ignore"):
                yhat, J = problem.predict_with_jacobian(theta)
            Jphi = J[:, free] * theta[free]
            if band:
                yhat, Jphi = band(yhat), band(Jphi)
            r = yhat - y
            trace.append({"iteration": len(trace), "cost": 0.5 * float(r @ r), "theta": theta.tolist()})
            if not np.all(np.isfinite(Jphi)):
                return np.zeros_like(Jphi)
            return Jphi

        jac = jacobian if self.options.jacobian == "exact" else "2-point"
        tol = dict(xtol=self.options.xtol, ftol=self.options.ftol) if final else dict(xtol=1e-6, ftol=1e-8)
        res = least_squares(residual, phi0, jac=jac, method="lm", max_nfev=max_nfev, x_scale=1.0, **tol)
        theta = theta_of(res.x)
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


@hookimpl
def mbus_solvers():
    return [SolverSpec("scipy_lm", ScipyLM, ScipyLM.summary)]
