"""Nuisance parameters of a real rig: an input gain and a pure delay (trigger offset).

The recorded input is a voltage (or a force known only up to scale) and the scope's trigger
may be offset; the Section 8.2 future-work note asks for both before trusting sound speeds.
The prediction becomes

    yhat(t_k) = g * y_model(t_k - tau)

with g [N per input unit] and tau [s]. With a zero-order-hold input the delayed response is
exact: writing tau = (m + f) h (m integer, 0 <= f < 1) and s = (1 - f) h,

    y(t_k - tau) = y(j h + s),   j = k - m - 1,
    y(j h + s)   = C e^{A s} x_j + (C Gamma(s) + D) u_j,   Gamma(s) = int_0^s e^{A r} dr B

i.e. the same discrete system read through the output matrix C e^{A s}, shifted by m + 1
samples. Its derivative is the output rate, again a linear read-out of the same states:

    d yhat / d tau = -g (C A e^{A s} x_j + C e^{A s} B u_j).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from mbus_framework.interfaces.model import Parameter, StateSpace
from mbus_framework.engine.simulation import simulate_ss, simulate_with_sensitivities

GAIN = "input_gain"
DELAY = "delay"


@dataclass(frozen=True)
class NuisanceSettings:
    """Which nuisance parameters exist, their values (when fixed) and whether to estimate."""

    estimate_gain: bool = False
    gain: float = 1.0
    estimate_delay: bool = False
    delay: float = 0.0
    max_delay: float | None = None

    @property
    def active(self) -> bool:
        return self.estimate_gain or self.estimate_delay or self.gain != 1.0 or self.delay != 0.0

    def parameters(self, dt: float, duration: float) -> list[Parameter]:
        max_delay = self.max_delay if self.max_delay is not None else duration / 2
        return [
            Parameter(GAIN, "N/unit", "gain from the recorded input to force", 0.0, np.inf, 1.0, 0.0),
            Parameter(DELAY, "s", "pure delay (trigger offset)", 0.0, max_delay, dt, -1.0, log_scale=False),
        ]


def _intermediate_readout(ss: StateSpace, s: float) -> tuple[StateSpace, StateSpace]:
    """Systems whose sampled outputs are y(jh + s) and dy/dt(jh + s) for a ZOH input."""
    A, B, C, D = (np.atleast_2d(m) for m in ss)
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1), dtype=np.result_type(A, B, float))
    M[:n, :n] = A * s
    M[:n, n:] = B * s
    E = expm(M)
    Es, Gs = E[:n, :n], E[:n, n:]
    value = StateSpace(A, B, C @ Es, C @ Gs + D)
    rate = StateSpace(A, B, C @ A @ Es, C @ Es @ B)
    return value, rate


class _DelayedReadout:
    """Adapter: a model whose output is read at offset s inside each sample interval."""

    def __init__(self, model, s: float):
        self.model, self.s = model, s

    def state_space(self, theta) -> StateSpace:
        return _intermediate_readout(self.model.state_space(theta), self.s)[0]


def _split_delay(delay: float, dt: float) -> tuple[int, float]:
    """tau = (m + f) h  ->  (m + 1, s = (1 - f) h) with the shift m + 1 >= 1."""
    q = max(delay, 0.0) / dt
    m = int(np.floor(q))
    f = q - m
    return m + 1, (1.0 - f) * dt


def _shift(x: np.ndarray, k: int) -> np.ndarray:
    """Delay along axis 0 by k samples, zeros (rest) in front."""
    out = np.zeros_like(x)
    if k < x.shape[0]:
        out[k:] = x[: x.shape[0] - k]
    return out


def delayed_prediction(model, theta, u, dt, gain: float, delay: float) -> np.ndarray:
    """g * y_model(t_k - tau) for a ZOH input (exact)."""
    theta = np.asarray(theta, dtype=float)
    if not getattr(model, "has_state_space", True):
        from mbus_framework.engine.convolution import simulate_response

        return simulate_response(model, theta, u, dt, "zoh", gain, delay)
    if delay == 0.0:
        from mbus_framework.engine.simulation import simulate

        return gain * simulate(model, theta, u, dt)
    shift, s = _split_delay(delay, dt)
    ys = simulate_ss(_intermediate_readout(model.state_space(theta), s)[0], u, dt)
    return gain * _shift(ys, shift)


def delayed_prediction_with_jacobian(model, theta, u, dt, gain: float, delay: float):
    """(yhat, d yhat/d theta_model, d yhat/d gain, d yhat/d tau), all exact for ZOH."""
    theta = np.asarray(theta, dtype=float)
    if not getattr(model, "has_state_space", True):
        from mbus_framework.engine.convolution import simulate_response_with_sensitivities

        return simulate_response_with_sensitivities(model, theta, u, dt, "zoh", gain, float(delay))
    shift, s = _split_delay(delay, dt)
    ys, Js = simulate_with_sensitivities(_DelayedReadout(model, s), theta, u, dt)
    rate = simulate_ss(_intermediate_readout(model.state_space(theta), s)[1], u, dt)
    y = _shift(ys, shift)
    return gain * y, gain * _shift(Js, shift), y, -gain * _shift(rate, shift)
