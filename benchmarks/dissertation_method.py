"""The dissertation's identification method (Chapter 3.2.3), re-implemented for comparison.

Forward model: classical fourth-order Runge-Kutta at the sample rate (eq. 3.22),

    k1 = f(t, z, u(t))
    k2 = f(t + h/2, z + (h/2) k1, u(t + h/2))
    k3 = f(t + h/2, z + (h/2) k2, u(t + h/2))
    k4 = f(t + h, z + h k3, u(t + h))
    z_{j+1} = z_j + (h/6) (k1 + 2 k2 + 2 k3 + k4),      f(t, z, u) = A z + B u,

one step per sample (h = 1 / sample rate [s]), output y_j = C z_j + D u_j.

Choices, documented because the text leaves them open:

* Eq. 3.22 as printed adds k1/2 (not h k1/2) to z and multiplies the sum by h at the end,
  mixing the slope and increment forms; it denotes the classical method, implemented here.
* The input is known only at the samples. It is held over the step,
  u(t + h/2) = u(t + h) = u_j: the sampled PRBS played by the function generator is a
  zero-order-hold signal, so RK4 then approximates the same continuous problem the exact
  engine solves (ZOH), and its error against the exact solution is RK4's own truncation
  error (~1e-5 relative for Table 3.1). Using u_{j+1} for u(t+h) would put every PRBS edge
  half a step early and give O(1) differences at the edges instead.
* The loop is a plain per-sample Python loop over numpy matrix-vector products, as the
  original MATLAB was a per-sample loop; no vectorisation across samples.

Jacobian: forward differences with 1 % increments (Table 3.1, "Increment step for
J-matrix = 1 %"): J_i = (y(theta + 0.01 theta_i e_i) - y(theta)) / (0.01 theta_i), reusing
y(theta) from the residual, i.e. p extra simulations per Jacobian.

Levenberg-Marquardt (eqs. 3.23-3.27), shared by both methods in the benchmark:

    Delta = (J'J + lambda I)^-1 J' (y - yhat)        (eq. 3.25)
    theta_{i+1} = theta_i + Delta                    (eq. 3.24)

in parameters normalised by the initial values, vartheta = theta / theta_0 (so the single
lambda I is dimensionless; with raw parameters k ~ 1e8 and b ~ 10, J'J has a condition
number ~1e30 and lambda I is meaningless). Marquardt's lambda update: a step that lowers the
sum of squares is accepted and lambda /= 10; otherwise it is rejected and lambda *= 10.
lambda starts at 1e-2 times the mean diagonal of J'J. A step that makes a parameter
non-positive counts as rejected. Stop when an accepted step changes the cost by less than
``ftol`` relatively or every parameter by less than ``xtol`` relatively, or after
``max_iter`` iterations (the dissertation stops at an absolute MSE, e.g. 1e-12, which noisy
data never reaches).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from mbus_framework.interfaces.model import MediumModel
from mbus_framework.engine.simulation import as_float_ss, simulate, simulate_with_sensitivities


def rk4_simulate(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
    """Output y (N,) of dz/dt = A z + B u, y = C z + D u from rest by RK4, one step per sample.

    u is held over each step (see the module docstring); h is the sample interval [s].
    """
    A = np.asarray(A, float)
    b = np.asarray(B, float).reshape(-1)
    c = np.asarray(C, float).reshape(-1)
    d = float(np.asarray(D, float).reshape(-1)[0])
    z = np.zeros(A.shape[0])
    y = np.empty(u.size)
    half, sixth = 0.5 * h, h / 6.0
    for j in range(u.size):
        uj = u[j]
        y[j] = c @ z + d * uj
        bu = b * uj
        k1 = A @ z + bu
        k2 = A @ (z + half * k1) + bu
        k3 = A @ (z + half * k2) + bu
        k4 = A @ (z + h * k3) + bu
        z = z + sixth * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return y


class ForwardModel(Protocol):
    """What the LM iteration needs: a simulation and a Jacobian at a parameter vector."""

    name: str

    def simulate(self, theta: np.ndarray) -> np.ndarray: ...

    def jacobian(self, theta: np.ndarray, y: np.ndarray) -> np.ndarray:
        """d yhat / d theta (N, p) at theta, where y = yhat(theta) is already known."""


@dataclass
class Rk4ForwardDifference:
    """The dissertation's forward model: RK4 simulation, 1 % forward-difference Jacobian."""

    model: MediumModel
    u: np.ndarray
    dt: float
    increment: float = 0.01
    name: str = "dissertation (RK4 + 1% forward differences)"

    def simulate(self, theta):
        A, B, C, D = as_float_ss(self.model.state_space(np.asarray(theta, float)))
        return rk4_simulate(A, B, C, D, self.u, self.dt)

    def jacobian(self, theta, y):
        theta = np.asarray(theta, float)
        J = np.empty((y.size, theta.size))
        for i in range(theta.size):
            step = self.increment * theta[i]
            tp = theta.copy()
            tp[i] += step
            J[:, i] = (self.simulate(tp) - y) / step
        return J


@dataclass
class ExactEngine:
    """mbus engine: exact ZOH simulation and exact sensitivities."""

    model: MediumModel
    u: np.ndarray
    dt: float
    name: str = "engine (exact ZOH + exact sensitivities)"

    def simulate(self, theta):
        return simulate(self.model, theta, self.u, self.dt, "zoh")

    def jacobian(self, theta, y):
        return simulate_with_sensitivities(self.model, theta, self.u, self.dt, "zoh")[1]


@dataclass
class EngineForwardDifference(ExactEngine):
    """Exact simulation with the dissertation's 1 % forward-difference Jacobian (for separating
    the effect of the Jacobian from that of the simulator)."""

    increment: float = 0.01
    name: str = "engine simulation + 1% forward differences"

    def jacobian(self, theta, y):
        theta = np.asarray(theta, float)
        J = np.empty((y.size, theta.size))
        for i in range(theta.size):
            step = self.increment * theta[i]
            tp = theta.copy()
            tp[i] += step
            J[:, i] = (self.simulate(tp) - y) / step
        return J


@dataclass
class LMResult:
    theta: np.ndarray
    cost: float  # 1/2 sum of squared residuals
    iterations: int
    n_simulations: int  # trial simulations (residuals)
    n_jacobians: int
    converged: bool
    message: str
    wall_time_s: float
    history: list[dict] = field(default_factory=list)


def levenberg_marquardt(
    fm: ForwardModel,
    y_measured: np.ndarray,
    theta0: np.ndarray,
    *,
    lambda_factor: float = 10.0,
    lambda0_relative: float = 1e-2,
    ftol: float = 1e-10,
    xtol: float = 1e-9,
    max_iter: int = 100,
    callback: Callable[[dict], None] | None = None,
) -> LMResult:
    """Eq. 3.25 with Marquardt's lambda update, in parameters normalised by ``theta0``."""
    t0 = time.perf_counter()
    scale = np.asarray(theta0, float).copy()
    theta = scale.copy()
    y_hat = fm.simulate(theta)
    n_sim, n_jac = 1, 0
    r = y_measured - y_hat
    cost = 0.5 * float(r @ r)
    lam = None
    history = [{"iteration": 0, "cost": cost, "theta": theta.tolist()}]
    converged, message = False, "maximum number of iterations reached"
    need_jacobian = True
    it = 0
    for it in range(1, max_iter + 1):
        if need_jacobian:
            Js = fm.jacobian(theta, y_hat) * scale  # d yhat / d vartheta
            n_jac += 1
            JtJ = Js.T @ Js
            Jtr = Js.T @ r
            if lam is None:
                lam = lambda0_relative * float(np.mean(np.diag(JtJ)))
        step = np.linalg.solve(JtJ + lam * np.eye(theta.size), Jtr) * scale  # eq. 3.25
        trial = theta + step  # eq. 3.24
        if np.all(trial > 0):
            y_trial = fm.simulate(trial)
            n_sim += 1
            r_trial = y_measured - y_trial
            cost_trial = 0.5 * float(r_trial @ r_trial)
        else:
            cost_trial = np.inf
        if cost_trial < cost:
            rel_df = (cost - cost_trial) / cost
            rel_dx = float(np.max(np.abs(step / trial)))
            theta, y_hat, r, cost = trial, y_trial, r_trial, cost_trial
            lam /= lambda_factor
            need_jacobian = True
            history.append({"iteration": it, "cost": cost, "theta": theta.tolist(), "lambda": lam})
            if callback:
                callback(history[-1])
            if rel_df < ftol or rel_dx < xtol:
                converged, message = True, f"converged (relative cost change {rel_df:.1e}, step {rel_dx:.1e})"
                break
        else:
            lam *= lambda_factor
            need_jacobian = False
            if lam > 1e20:
                converged, message = True, "lambda overflow: no descent step exists (at a minimum)"
                break
    return LMResult(theta, cost, it, n_sim, n_jac, converged, message, time.perf_counter() - t0, history)
