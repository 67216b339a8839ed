"""``casadi_collocation`` solver: simultaneous output-error fit by direct collocation and IPOPT.

The states are decision variables and the model equations are constraints (CasADi builds the
NLP from the model's own ``state_space``, evaluated on symbolic parameters; no model-specific
code here). With h the sample interval, the input held over each interval (ZOH: u = u_k on
[t_k, t_k+1); FOH: linear from u_k to u_k+1) and collocation points 0 < tau_1 < ... < tau_d <= 1
(Gauss-Legendre or Radau IIA; trapezoidal = Lobatto IIIA with d = 1), each interval carries

    sum_j C_jr X_j = h (A(theta) X_r + B(theta) u(tau_r)),   r = 1..d       (collocation)
    x_k+1 = sum_j D_j X_j,   X_0 = x_k                                       (continuity)
    yhat_k = C(theta) x_k + D(theta) u_k,   minimise 1/2 sum_k (y_k - yhat_k)^2 / s_y^2

Gauss-Legendre of degree d is exact to order 2d at the samples, Radau IIA to order 2d - 1
(and L-stable). Measured on the Table 3.1 chain (|lambda| h ~ 0.12, 6200 samples), relative
RMS difference from the exact ZOH simulation: Legendre d=3 1e-10, d=2 2e-6, Radau d=3 2e-8,
d=2 2e-4, trapezoidal 1.2e-2 (frequency warping (w h)^2/12, which biases the stiffnesses by
about 1 %). At convergence the estimate is the output-error least-squares estimate of the
exact ZOH model up to that discretisation error (``extras.discretisation_error``).

**Structure exploitation** (``formulation: condensed``, the default). The model is linear in
its states, so the collocation equations of one interval are linear in (X_1..X_d) given
(x_k, u) and can be eliminated exactly: with the augmented matrix M = [[A, B], [0, 0]]

    [x_k+1; u] = R(h M) [x_k; u],   R(z) = P(z)/Q(z)

R the stability function of the collocation scheme ((d,d) Pade for Legendre, (d-1,d) for
Radau), evaluated symbolically once per NLP evaluation from the scaled matrices. The states
at the samples inside a node are eliminated too (they are linear in the node state), so the
NLP keeps only the states at every m-th sample (``samples_per_node``):

    xi_j+1 = Phi^m xi_j + G U_j,   Yhat_j = O xi_j + T U_j    (O = [C; C Phi; ...], T Toeplitz)

Both eliminations are exact: the optimum does not depend on m, only the NLP size and how
nonlinear the iterations are (m large approaches single shooting). ``auto`` chooses m so
the fastest mode turns by about ``node_phase`` radians per node. ``formulation: full`` keeps
every sample state and every collocation-point state as NLP variables (textbook direct
collocation, the intervals built with ``Function.map``); it gives the same optimum and is
kept for checking and for small records.

**Scaling.** Free parameters enter as z = theta / theta_start (default) or, with
``coordinates: log``, z = ln(theta / theta_start) for ``log_scale`` parameters (|z| <= 23), so
they are of order one; model bounds (and the strategy's search box) become bounds on z.
(Measured: linear coordinates end a lone local solve at the nearest local minimum, log ones
can run off by decades, e.g. from set 2 on the first 1500 Table 3.1 samples.) States are divided by their largest
magnitude in a simulation at the start parameters (which also balances h M before the
stability function is evaluated, needed for accuracy: entries of h M span ~1e-7..1e4 on the
Table 3.1 chain), the output by the record's RMS. The warm start is that simulation, so every
local solve starts feasible (constraint violation ~1e-15).

**Hessian.** ``gauss-newton`` (default) gives IPOPT sigma J^T J of the output residual
(J = d e / d(z, xi)), ignoring constraint curvature (generalised Gauss-Newton, as CasADi's
``sysid.py`` example); ``exact`` uses CasADi's second derivatives; ``limited-memory`` L-BFGS.

**Global strategy.** From a feasible (simulated) start the first constrained Gauss-Newton step
equals the single-shooting step, so the collocation NLP alone has local minima too. By
default each local solve is run inside the framework's global strategy
(:mod:`mbus_framework.estimation.strategy`: time-scale alignment, band continuation, multi-start); the
band-limited stages fit a causal 4th-order Butterworth-filtered residual whose filter states
join the NLP (same |H| as the strategy's zero-phase filter), so every stage stays sparse.
``global_search: false`` solves once from the initial values.

Uncertainty (``jacobian``) comes from the exact sensitivities of the exact ZOH model at the
estimate (``FitProblem.predict_with_jacobian``); IPOPT's statistics are in ``extras``.

The package: ``options`` (the config section), ``discretisation`` (collocation coefficients
and the symbolic transition), ``band_filter`` (band stages as a causal filter), ``nlp`` (the
NLP and IPOPT), ``solver`` (local solves inside the global strategy).
"""
from __future__ import annotations

from mbus_plugins.solvers.casadi_collocation.band_filter import (
    butterworth_ss,
    filter_data,
    filter_states,
)
from mbus_plugins.solvers.casadi_collocation.discretisation import (
    collocation_matrices,
    collocation_points,
    model_matrices_function,
    stability_polynomials,
    transition_function,
)
from mbus_plugins.solvers.casadi_collocation.options import CasadiCollocationOptions
from mbus_plugins.solvers.casadi_collocation.solver import CasadiCollocation

from mbus_framework.interfaces.hookspecs import SolverSpec, hookimpl

__all__ = ["CasadiCollocation", "CasadiCollocationOptions", "butterworth_ss", "collocation_matrices",
           "collocation_points", "filter_data", "filter_states", "model_matrices_function",
           "stability_polynomials", "transition_function"]


@hookimpl
def mbus_solvers():
    return [SolverSpec("casadi_collocation", CasadiCollocation, CasadiCollocation.summary)]
