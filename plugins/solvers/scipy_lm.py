"""``scipy_lm`` solver: Levenberg-Marquardt output-error fit with a global strategy.

Local solves are ``scipy.optimize.least_squares(method="lm")`` (MINPACK) on the residual
r = F(y - yhat(theta)), F an optional band-limiting filter of the continuation, in
log-parameters phi = ln(theta) (:mod:`mbus_framework.estimation.local`). The Jacobian is
exact, from the forward-sensitivity system; ``jacobian: finite_difference`` switches to
SciPy's 2-point differences for comparison. The global strategy is
:mod:`mbus_framework.estimation.strategy`.
"""
from __future__ import annotations

import time
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.interfaces.hookspecs import SolverSpec, hookimpl
from mbus_framework.estimation.problem import FitProblem, FitResult, Progress, Solver
from mbus_framework.estimation.local import Coordinates, lm_fit  # noqa: F401  (Coordinates: re-export)
from mbus_framework.estimation.strategy import BandFilter, LocalResult, StrategyOptions, search


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
        o = self.options
        return lm_fit(problem, theta0, band, max_nfev, final, o.jacobian, o.xtol, o.ftol)


@hookimpl
def mbus_solvers():
    return [SolverSpec("scipy_lm", ScipyLM, ScipyLM.summary)]
