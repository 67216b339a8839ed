"""Solver interface, the fitting problem every solver receives, and the common result.

The estimation problem (eqs. 3.23-3.27) is output-error least squares

    minimise  cost(theta) = 1/2 sum_k (y[k] - yhat[k; theta])^2

over the free model parameters theta > 0. Every solver returns a :class:`FitResult` with the
vocabulary of ``scipy.optimize.least_squares`` (success, status, message, nfev, njev, cost)
plus the run-level fields a scientist needs; solver-specific detail goes in ``extras``.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar

import numpy as np
from pydantic import BaseModel

from .model import MediumModel, NoOptions
from .simulation import Hold, simulate, simulate_with_sensitivities

OutputFilter = Callable[[np.ndarray, float], np.ndarray]


@dataclass
class FitProblem:
    """Data and model for one identification.

    t, u, y:   the record (t uniform [s]); u is the force, y the received force.
    initial:   starting parameters (full vector) or None to let the strategy choose.
    fixed:     mapping name -> value of parameters held fixed (not estimated).
    lower/upper: bounds on the full parameter vector.
    hold:      'zoh' or 'foh' input reconstruction between samples.
    output_filter: linear map applied to model outputs and sensitivities (compensators).
    """

    model: MediumModel
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    initial: np.ndarray | None = None
    fixed: dict[str, float] = field(default_factory=dict)
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    hold: Hold = "zoh"
    output_filter: OutputFilter | None = None

    def __post_init__(self):
        lo, hi = self.model.bounds()
        self.lower = lo if self.lower is None else np.asarray(self.lower, float)
        self.upper = hi if self.upper is None else np.asarray(self.upper, float)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def names(self) -> list[str]:
        return self.model.parameter_names

    @property
    def free(self) -> np.ndarray:
        """Boolean mask of estimated parameters."""
        return np.array([n not in self.fixed for n in self.names])

    def full(self, free_values: np.ndarray, template: np.ndarray) -> np.ndarray:
        """Full parameter vector from free values, fixed values taken from ``fixed``."""
        theta = np.array(template, dtype=float)
        for i, n in enumerate(self.names):
            if n in self.fixed:
                theta[i] = self.fixed[n]
        theta[self.free] = free_values
        return theta

    def predict(self, theta: np.ndarray) -> np.ndarray:
        yhat = simulate(self.model, theta, self.u, self.dt, self.hold)
        return self.output_filter(yhat, self.dt) if self.output_filter else yhat

    def predict_with_jacobian(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Prediction (N,) and exact d yhat / d theta (N, p) for the full vector."""
        yhat, J = simulate_with_sensitivities(self.model, theta, self.u, self.dt, self.hold)
        if self.output_filter:
            yhat, J = self.output_filter(yhat, self.dt), self.output_filter(J, self.dt)
        return yhat, J


@dataclass
class FitResult:
    """Common result of every solver (``least_squares`` vocabulary).

    theta:       estimated full parameter vector, ordered as ``names``
    success:     True when the solver reports convergence
    status:      solver's integer status (scipy convention: > 0 converged)
    message:     solver's own words
    nfev, njev:  function and Jacobian evaluations (all starts together)
    iterations:  iterations of the winning local solve
    cost:        1/2 sum of squared residuals at theta
    wall_time_s: elapsed wall-clock time
    residuals:   y - yhat at theta;  jacobian: d yhat/d theta at theta (free columns)
    trace:       per-iteration records {'iteration', 'cost', 'theta'} of the winning solve
    strategy:    what the global strategy tried and what won
    extras:      solver-specific detail
    """

    names: list[str]
    theta: np.ndarray
    success: bool
    status: int
    message: str
    nfev: int
    njev: int
    iterations: int
    cost: float
    wall_time_s: float
    residuals: np.ndarray
    jacobian: np.ndarray | None = None
    free: np.ndarray | None = None
    trace: list[dict[str, Any]] = field(default_factory=list)
    strategy: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def parameters(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.theta)}


class Solver(ABC):
    """Base class of solver plugins; ``options`` is an instance of ``Options``."""

    Options: ClassVar[type[BaseModel]] = NoOptions
    summary: ClassVar[str] = ""

    def __init__(self, options: BaseModel):
        self.options = options

    @abstractmethod
    def solve(self, problem: FitProblem, progress: "Progress | None" = None) -> FitResult:
        """Estimate the free parameters of ``problem``."""


class Progress:
    """Minimal progress sink; the CLI passes a live display, tests pass nothing."""

    def start(self, description: str, total: int | None = None) -> None: ...

    def advance(self, steps: int = 1, note: str = "") -> None: ...

    def stop(self) -> None: ...
