"""Routing of the search: records the time-domain starts cannot explain go to the pole starts.

A lightly damped chain rings in spectral lines narrower than the scan's grid
(:mod:`~mbus_framework.estimation.poles`); a start outside the line's narrow basin ends where
the model predicts (almost) nothing, a stiffness or damping on the region's edge. Such an end is
a *null* end: its cost is that of a zero model output,

    J_0 = ½ Σ_k y_k²   (the record's energy; the residual r = y - 0),

and a cost J >= (1 - f) J_0 explains less than the fraction f of the record. When every
time-domain end so far is null and the record's subspace-identified poles z_i ring, i.e. the
least damping ratio

    ζ_i = -Re(s_i) / |s_i|,   s_i = ln(z_i) / Δt   [Δt: sample interval, s]

is below ``light_damping`` (0.002: nearly undamped chains are identified at 1e-4 to 1.5e-3,
a heavily damped record's spurious poles at 3e-3 and above), the pole starts are tried before
the scan (``StrategyOptions.poles_first``). Noise-dominated records end null by nature (the best
model explains little of them): a record whose energy is less than twice the noise's,
J_0 < 2 · ½ N σ² (σ² the model-free noise variance of
:func:`~mbus_framework.estimation.acceptance.estimate_noise`), keeps the usual order.
"""
from __future__ import annotations

import numpy as np

from mbus_framework.estimation.poles import record_poles


def null_cost(y: np.ndarray) -> float:
    """J_0 = ½ Σ y² [cost units]: the output-error cost of a model that predicts zero."""
    y = np.asarray(y, float)
    return 0.5 * float(y @ y)


def all_null(costs: list[float], null: float, fraction: float) -> bool:
    """True when there are costs and every one explains less than ``fraction`` of ``null``."""
    return bool(costs) and null > 0 and min(costs) >= (1.0 - fraction) * null


def noise_dominated(null: float, n: int, noise_var: float | None) -> bool:
    """True when the record's energy ``null`` = J_0 is below 2 · ½ N σ²: at least half of it is
    noise (False when the noise variance is unknown)."""
    return noise_var is not None and np.isfinite(noise_var) and null < float(n) * noise_var


def least_damping(z: np.ndarray, dt: float) -> float:
    """Least damping ratio ζ = -Re(s)/|s| of the oscillating discrete poles z (s = ln z / Δt);
    inf when none oscillates (no pole off the real axis) or none is stable."""
    z = np.asarray(z, complex)
    z = z[(np.abs(z.imag) > 1e-12) & (np.abs(z) > 0) & (np.abs(z) < 1)]
    if z.size == 0:
        return np.inf
    s = np.log(z) / dt
    return float(np.min(-s.real / np.abs(s)))


def record_damping(problem, z: np.ndarray | None = None) -> float:
    """Least damping ratio of the record's poles identified at the model's order (inf when the
    model has no states or identification fails); ``z``: those poles when already identified
    (:func:`~mbus_framework.estimation.poles.identified_poles`)."""
    order = getattr(problem.model, "n_states", 0)
    if not getattr(problem.model, "has_state_space", True) or not order:
        return np.inf
    if z is None:
        try:
            z = record_poles(problem.u, problem.y, int(order))
        except (np.linalg.LinAlgError, ValueError, MemoryError):
            return np.inf
    return least_damping(z, problem.dt)
