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

from mbus_framework.interfaces.model import MediumModel, NoOptions, Parameter
from mbus_framework.estimation.nuisance import DELAY, GAIN, NuisanceSettings, delayed_prediction, delayed_prediction_with_jacobian
from mbus_framework.estimation.progress import Progress  # noqa: F401 - re-exported: plugins import it from here
from mbus_framework.engine.simulation import Hold, simulate, simulate_with_sensitivities

OutputFilter = Callable[[np.ndarray, float], np.ndarray]


class SearchTimeout(Exception):
    """Raised by a :attr:`FitProblem.monitor` when the search's time budget has run out."""


@dataclass
class FitProblem:
    """Data and model for one identification.

    t, u, y:   the record (t uniform [s]); u is the force, y the received force.
    initial:   starting parameters (full vector) or None to let the strategy choose.
    fixed:     mapping name -> value of parameters held fixed (not estimated).
    lower/upper: bounds on the full parameter vector.
    hold:      'zoh' or 'foh' input reconstruction between samples.
    output_filter: linear map applied to model outputs and sensitivities (compensators).
    nuisance:  input gain and delay (:mod:`mbus_framework.estimation.nuisance`); when active, the
               parameter vector is the model's followed by ``input_gain`` and ``delay``.
    noise_filter: the linear map a compensator applied to the record (its noise is then
               coloured), or None for white noise.
    monitor:   called before every model evaluation (the strategy's time budget and progress;
               it may raise :class:`SearchTimeout`), or None.
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
    nuisance: NuisanceSettings = field(default_factory=NuisanceSettings)
    noise_filter: Any = None
    monitor: Callable[[], None] | None = None

    def __post_init__(self):
        self.t, self.u, self.y = (np.asarray(a, dtype=float) for a in (self.t, self.u, self.y))
        if self.nuisance.active and self.hold != "zoh":
            raise ValueError("an input gain or delay needs hold='zoh'")
        # the model's parameter list, read once (a model builds it on every access; the search
        # asks for it thousands of times)
        self._model_parameters = (self.model, tuple(self.model.parameters))
        params = self.parameters
        lo = np.array([p.lower for p in params], dtype=float)
        hi = np.array([p.upper for p in params], dtype=float)
        self.lower = lo if self.lower is None else np.asarray(self.lower, float)
        self.upper = hi if self.upper is None else np.asarray(self.upper, float)
        fixed = dict(self.fixed)
        if self.nuisance.active:
            if not self.nuisance.estimate_gain:
                fixed.setdefault(GAIN, self.nuisance.gain)
            if not self.nuisance.estimate_delay:
                fixed.setdefault(DELAY, self.nuisance.delay)
        self.fixed = fixed

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def parameters(self) -> list[Parameter]:
        """The model's parameters, then the nuisance parameters when active."""
        params = list(self._own_parameters())
        if self.nuisance.active:
            params += self.nuisance.parameters(self.dt, float(self.t[-1] - self.t[0]))
        return params

    @property
    def n_model(self) -> int:
        """Number of leading entries of theta that belong to the medium model."""
        return len(self._own_parameters())

    def _own_parameters(self) -> tuple[Parameter, ...]:
        model, params = getattr(self, "_model_parameters", (None, ()))
        if model is not self.model:  # the model was replaced after construction
            params = tuple(self.model.parameters)
            self._model_parameters = (self.model, params)
        return params

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parameters]

    def default_initial(self) -> np.ndarray:
        """The model's physics-based guess, plus the configured nuisance values."""
        guess = list(np.asarray(self.model.initial_guess(self.t, self.u, self.y), dtype=float))
        if self.nuisance.active:
            guess += [self.nuisance.gain, self.nuisance.delay]
        return np.array(guess)

    def split(self, theta: np.ndarray) -> tuple[np.ndarray, float, float]:
        """(model parameters, gain, delay)."""
        theta = np.asarray(theta, dtype=float)
        if not self.nuisance.active:
            return theta, 1.0, 0.0
        n = self.n_model
        return theta[:n], float(theta[n]), float(theta[n + 1])

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
        if self.monitor is not None:
            self.monitor()
        model_theta, gain, delay = self.split(theta)
        if self.nuisance.active:
            yhat = delayed_prediction(self.model, model_theta, self.u, self.dt, gain, delay)
        else:
            yhat = simulate(self.model, model_theta, self.u, self.dt, self.hold)
        return self.output_filter(yhat, self.dt) if self.output_filter else yhat

    def predict_with_jacobian(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Prediction (N,) and exact d yhat / d theta (N, p) for the full vector."""
        if self.monitor is not None:
            self.monitor()
        model_theta, gain, delay = self.split(theta)
        if self.nuisance.active:
            yhat, Jm, dgain, ddelay = delayed_prediction_with_jacobian(
                self.model, model_theta, self.u, self.dt, gain, delay
            )
            J = np.column_stack([Jm, dgain, ddelay])
        else:
            yhat, J = simulate_with_sensitivities(self.model, model_theta, self.u, self.dt, self.hold)
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

    @classmethod
    def at_estimate(cls, problem: "FitProblem", best, *, nfev: int, njev: int, wall_time_s: float,
                    strategy: dict[str, Any], extras: dict[str, Any]) -> "FitResult":
        """The common result for a solver's best local solve (a ``strategy.LocalResult``):
        residuals, cost and the exact Jacobian (free columns) evaluated at the estimate."""
        yhat, J = problem.predict_with_jacobian(best.theta)
        residuals = problem.y - yhat
        return cls(
            names=problem.names,
            theta=best.theta,
            success=best.status > 0,
            status=best.status,
            message=best.message,
            nfev=nfev,
            njev=njev,
            iterations=best.iterations,
            cost=0.5 * float(residuals @ residuals),
            wall_time_s=wall_time_s,
            residuals=residuals,
            jacobian=J[:, problem.free],
            free=problem.free,
            trace=best.trace,
            strategy=strategy,
            extras=extras,
        )


class Solver(ABC):
    """Base class of solver plugins; ``options`` is an instance of ``Options``.

    ``periodic_records``: the solver needs a periodic record (an input repeating with an
    integer number of samples per period, at least two periods); the contract suites then
    give it one."""

    Options: ClassVar[type[BaseModel]] = NoOptions
    summary: ClassVar[str] = ""
    periodic_records: ClassVar[bool] = False

    def __init__(self, options: BaseModel):
        self.options = options

    @abstractmethod
    def solve(self, problem: FitProblem, progress: "Progress | None" = None) -> FitResult:
        """Estimate the free parameters of ``problem``."""
