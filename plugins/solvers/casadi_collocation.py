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
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from mbus_framework.errors import EstimationError
from mbus_framework.interfaces.hookspecs import SolverSpec, hookimpl
from mbus_framework.estimation.nuisance import DELAY, GAIN
from mbus_framework.engine.simulation import as_float_ss, discretize
from mbus_framework.estimation.problem import FitProblem, FitResult, Progress, Solver
from mbus_framework.estimation.strategy import BandFilter, LocalResult, StrategyOptions, search

LOG_RANGE = 23.0  # a log-parameter moves at most e^23 ~ 1e10 from the start of a local solve
IPOPT_STATUS = {
    "Solve_Succeeded": 1,
    "Solved_To_Acceptable_Level": 2,
    "Search_Direction_Becomes_Too_Small": 3,
    "Maximum_Iterations_Exceeded": 0,
    "Maximum_CpuTime_Exceeded": 0,
    "Maximum_WallTime_Exceeded": 0,
}


class CasadiCollocationOptions(BaseModel):
    """Options of ``casadi_collocation`` (the ``solver.options`` config section)."""

    model_config = ConfigDict(extra="forbid")
    scheme: Literal["legendre", "radau", "trapezoidal"] = Field(
        "legendre", description="collocation points: Gauss-Legendre, Radau IIA, or the trapezoidal rule"
    )
    degree: int = Field(3, ge=1, le=9, description="collocation points per sample interval (trapezoidal: 1)")
    formulation: Literal["condensed", "full"] = Field(
        "condensed",
        description="condensed: collocation and intra-node states eliminated exactly (linear model); "
        "full: every sample and collocation-point state is an NLP variable",
    )
    samples_per_node: int | Literal["auto"] = Field(
        "auto", description="condensed: samples between NLP state nodes (no effect on the optimum)"
    )
    node_phase: float = Field(2.0, gt=0, description="auto: radians the fastest mode turns per node")
    coordinates: Literal["linear", "log"] = Field(
        "linear", description="NLP coordinates of log-scale parameters: theta/theta_start or ln(theta/theta_start)"
    )
    hessian: Literal["gauss-newton", "exact", "limited-memory"] = Field(
        "gauss-newton", description="Hessian of the Lagrangian given to IPOPT"
    )
    tol: float = Field(1e-10, gt=0, description="IPOPT tol (scaled NLP)")
    xtol: float = Field(1e-10, gt=0, description="final solve also stops at this relative parameter step")
    ftol: float = Field(1e-12, gt=0, description="final solve also stops at this relative cost change")
    stage_xtol: float = Field(1e-5, gt=0, description="search stages stop at this relative parameter step")
    stage_ftol: float = Field(1e-8, gt=0, description="search stages stop at this relative cost change")
    max_iter: int = Field(300, ge=1, description="IPOPT iteration limit of the final solve")
    global_search: bool = Field(True, description="run the local solves inside the global strategy")
    strategy: StrategyOptions = Field(default_factory=StrategyOptions)
    search_samples: int | None = Field(
        None, ge=16, description="run the global search on the first n samples only (final solve: whole record)"
    )
    print_level: int | None = Field(
        None, ge=0, le=12, description="IPOPT print_level; default 5 on an interactive terminal, else 0"
    )
    ipopt: dict[str, float | int | str] = Field(
        default_factory=dict, description="further IPOPT options, e.g. {mu_strategy: adaptive}"
    )

    @field_validator("samples_per_node")
    @classmethod
    def _positive(cls, v):
        if v != "auto" and v < 1:
            raise ValueError("samples_per_node must be 'auto' or >= 1")
        return v


# ---------------------------------------------------------------------------------------------
# collocation coefficients
# ---------------------------------------------------------------------------------------------
def collocation_points(degree: int, scheme: str) -> np.ndarray:
    """tau_1..tau_d in (0, 1] of a collocation scheme (trapezoidal: [0, 1])."""
    import casadi as ca

    if scheme == "trapezoidal":
        return np.array([0.0, 1.0])
    return np.array(ca.collocation_points(degree, scheme), dtype=float)


def collocation_matrices(degree: int, scheme: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tau, Cd, Dc) on [0, tau_1..tau_d]: Cd[j, r] = l_j'(tau_r), Dc[j] = l_j(1) (Lagrange basis)."""
    tau = np.concatenate([[0.0], collocation_points(degree, scheme)])
    k = tau.size
    Cd, Dc = np.zeros((k, k)), np.zeros(k)
    for j in range(k):
        p = np.poly1d([1.0])
        for r in range(k):
            if r != j:
                p *= np.poly1d([1.0, -tau[r]]) / (tau[j] - tau[r])
        Dc[j] = p(1.0)
        dp = np.polyder(p)
        Cd[j] = [dp(v) for v in tau]
    return tau, Cd, Dc


def stability_polynomials(degree: int, scheme: str) -> tuple[np.ndarray, np.ndarray]:
    """Ascending coefficients of P, Q with R(z) = P(z)/Q(z) the scheme's stability function.

    As a Runge-Kutta method with matrix A_rk and weights b: Q(z) = det(I - z A_rk),
    P(z) = det(I - z A_rk + z 1 b^T); trapezoidal: P = 1 + z/2, Q = 1 - z/2.
    """
    if scheme == "trapezoidal":
        return np.array([1.0, 0.5]), np.array([1.0, -0.5])
    tau = collocation_points(degree, scheme)
    d = tau.size
    A_rk, b = np.zeros((d, d)), np.zeros(d)
    for j in range(d):
        p = np.poly1d([1.0])
        for r in range(d):
            if r != j:
                p *= np.poly1d([1.0, -tau[r]]) / (tau[j] - tau[r])
        P = np.polyint(p)
        b[j] = P(1.0) - P(0.0)
        A_rk[:, j] = [P(v) - P(0.0) for v in tau]
    # det(I - z K) = prod(1 - z lambda_i): np.poly gives prod(x - lambda_i) with the
    # coefficient of x^(d-k) equal to that of z^k here.
    q = np.real(np.poly(np.linalg.eigvals(A_rk)))
    p = np.real(np.poly(np.linalg.eigvals(A_rk - np.outer(np.ones(d), b))))
    return p, q


# ---------------------------------------------------------------------------------------------
# symbolic model pieces
# ---------------------------------------------------------------------------------------------
def _symbolic_state_space(model, theta_sym):
    import casadi as ca

    from mbus_framework.engine.arrays import to_casadi

    k = theta_sym.numel()
    ss = model.state_space(np.array([theta_sym[i] for i in range(k)], dtype=object))
    A, B, C, D = (ca.SX(to_casadi(m)) for m in ss)
    return A, B, C, D


def _augmented(A, B, s_x, s_u, hold: str, h: float):
    """Scaled augmented matrix M~ = S^-1 M S of z = [x; u] (ZOH) or [x; u; h du/dt] (FOH)."""
    import casadi as ca

    n = A.size1()
    As = A * (ca.repmat(1.0 / s_x, 1, n) * ca.repmat(s_x.T, n, 1))
    Bs = B * s_u / s_x
    if hold == "zoh":
        return ca.vertcat(ca.horzcat(As, Bs), ca.SX.zeros(1, n + 1))
    top = ca.horzcat(As, Bs, ca.SX.zeros(n, 1))
    mid = ca.horzcat(ca.SX.zeros(1, n + 1), ca.SX(1.0 / h))
    return ca.vertcat(top, mid, ca.SX.zeros(1, n + 2))


def _rational(p, q, Z):
    """Q(Z)^-1 P(Z) by Horner."""
    import casadi as ca

    I = ca.SX.eye(Z.size1())

    def horner(c):
        R = c[-1] * I
        for v in c[-2::-1]:
            R = ca.mtimes(R, Z) + v * I
        return R

    return ca.solve(horner(q), horner(p))


def transition_function(model, n_theta: int, h: float, degree: int, scheme: str, hold: str, step: float | None = None):
    """SX function (theta_model, s_x, s_u) -> (Phi~, Gamma~, C~, D~) of one collocation step.

    Scaled coordinates xi = x / s_x, v = u / s_u:  xi_k+1 = Phi~ xi_k + Gamma~ [v_k (; v_k+1)],
    yhat_k = C~ xi_k + D~ v_k. ``step`` (< h) gives the state at t_k + step instead (readout
    of a delayed output). FOH: Gamma~ has the columns of v_k and v_k+1.
    """
    import casadi as ca

    theta = ca.SX.sym("theta", n_theta)
    A, B, C, D = _symbolic_state_space(model, theta)
    n = A.size1()
    s_x = ca.SX.sym("s_x", n)
    s_u = ca.SX.sym("s_u")
    M = _augmented(A, B, s_x, s_u, hold, h)
    p, q = stability_polynomials(degree, scheme)
    E = _rational(p, q, (h if step is None else step) * M)
    Phi = E[:n, :n]
    if hold == "zoh":
        Gam = E[:n, n]
    else:  # [v_k; v_k+1 - v_k] -> columns for v_k and v_k+1
        G1, G2 = E[:n, n], E[:n, n + 1]
        Gam = ca.horzcat(G1 - G2, G2)
    Cs = C * s_x.T
    Ds = D * s_u
    return ca.Function("transition", [theta, s_x, s_u], [Phi, Gam, Cs, Ds], ["theta", "s_x", "s_u"],
                       ["Phi", "Gamma", "C", "D"])


def model_matrices_function(model, n_theta: int):
    """SX function (theta_model, s_x, s_u) -> (A~, B~, C~, D~) in scaled coordinates."""
    import casadi as ca

    theta = ca.SX.sym("theta", n_theta)
    A, B, C, D = _symbolic_state_space(model, theta)
    n = A.size1()
    s_x = ca.SX.sym("s_x", n)
    s_u = ca.SX.sym("s_u")
    As = A * (ca.repmat(1.0 / s_x, 1, n) * ca.repmat(s_x.T, n, 1))
    return ca.Function("matrices", [theta, s_x, s_u], [As, B * s_u / s_x, C * s_x.T, D * s_u],
                       ["theta", "s_x", "s_u"], ["A", "B", "C", "D"])


# ---------------------------------------------------------------------------------------------
# band filter as a causal state-space system
# ---------------------------------------------------------------------------------------------
def butterworth_ss(cutoff_hz: float, dt: float, order: int = 4):
    """Discrete Butterworth low-pass (bilinear), |H| = 1/sqrt(1 + (f/fc)^(2 order)), as (Af, Bf, Cf, Df).

    Built as a cascade of second-order sections, each in transposed direct form II
    (z1' = -a1 z1 + z2 + (b1 - a1 b0) x, z2' = -a2 z1 + (b2 - a2 b0) x, y = z1 + b0 x).
    """
    from scipy import signal

    wn = min(cutoff_hz / (0.5 / dt), 0.999)
    sos = signal.butter(order, wn, output="sos")
    A = np.zeros((0, 0))
    B, C, D = np.zeros(0), np.zeros(0), 1.0
    for b0, b1, b2, _, a1, a2 in sos:
        As = np.array([[-a1, 1.0], [-a2, 0.0]])
        Bs = np.array([b1 - a1 * b0, b2 - a2 * b0])
        Cs = np.array([1.0, 0.0])
        k = A.shape[0]
        # cascade: this section is driven by the previous output C z + D x
        An = np.zeros((k + 2, k + 2))
        An[:k, :k] = A
        An[k:, :k] = np.outer(Bs, C)
        An[k:, k:] = As
        B = np.concatenate([B, Bs * D])
        C = np.concatenate([b0 * C, Cs])
        D = b0 * D
        A = An
    return A, B, C, float(D)


def filter_states(Af, Bf, x):
    """States z_k of z_k+1 = Af z_k + Bf x_k from rest, (nf, N)."""
    N = x.size
    Z = np.zeros((Af.shape[0], N))
    for k in range(N - 1):
        Z[:, k + 1] = Af @ Z[:, k] + Bf * x[k]
    return Z


def filter_data(Af, Bf, Cf, Df, x):
    """Output of the discrete filter (Af, Bf, Cf, Df) driven by ``x`` from rest."""
    return Cf @ filter_states(Af, Bf, x) + Df * x


# ---------------------------------------------------------------------------------------------
# the NLP
# ---------------------------------------------------------------------------------------------
@dataclass
class StageData:
    """Numerical inputs of one local solve (the NLP parameters) and its warm start."""

    theta_ref: np.ndarray  # full parameter vector at the start (scale of the free parameters)
    s_x: np.ndarray  # state scales
    s_y: float  # output scale
    y: np.ndarray  # (filtered) data on the prediction samples
    filt: tuple | None = None  # scaled filter (Af~, Bf~, Cf~, Df) of a band stage
    x0: np.ndarray | None = None


class _IterationLog:
    """IPOPT iteration callback: records (objective, free parameters) per iteration and stops
    the solve at a per-call iteration limit, or once the constraints are met (|g| < 1e-6,
    scaled) and the relative parameter step is below ``xtol`` or the relative objective change
    below ``ftol`` (as ``least_squares``' xtol/ftol; ``stop_reason`` says which)."""

    def __new__(cls, nx: int, ng: int, npar: int, n_free: int):
        import casadi as ca

        class _CB(ca.Callback):
            def __init__(self):
                ca.Callback.__init__(self)
                self.records: list[tuple[float, np.ndarray]] = []
                self.max_iter: int | None = None
                self.xtol: float | None = None
                self.ftol: float | None = None
                self.stop_reason = ""
                self.construct("iteration_log", {})

            def reset(self, max_iter: int | None, xtol: float | None, ftol: float | None):
                self.records, self.max_iter, self.stop_reason = [], max_iter, ""
                self.xtol, self.ftol = xtol, ftol

            def get_n_in(self):
                return ca.nlpsol_n_out()

            def get_n_out(self):
                return 1

            def get_name_in(self, i):
                return ca.nlpsol_out(i)

            def get_name_out(self, i):
                return "ret"

            def get_sparsity_in(self, i):
                name = ca.nlpsol_out(i)
                size = {"f": 1, "x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "lam_p": npar}[name]
                return ca.Sparsity.dense(size)

            def eval(self, arg):
                p = np.array(arg[0][:n_free], dtype=float).ravel()
                self.records.append((float(arg[1]), p))
                if self.max_iter is not None and len(self.records) > self.max_iter:
                    self.stop_reason = f"iteration limit ({self.max_iter})"
                    return [1]
                if len(self.records) >= 2:
                    g = np.array(arg[2], dtype=float).ravel()
                    if g.size and np.max(np.abs(g)) >= 1e-6:
                        return [0]
                    f0, p0 = self.records[-2]
                    f = self.records[-1][0]
                    # coordinates are theta / theta_start or ln(theta / theta_start): steps are relative
                    if self.xtol is not None and np.max(np.abs(p - p0)) < self.xtol:
                        self.stop_reason = f"relative parameter step below {self.xtol:g}"
                        return [1]
                    if self.ftol is not None and abs(f0 - f) <= self.ftol * max(abs(f), 1e-300):
                        self.stop_reason = f"relative cost change below {self.ftol:g}"
                        return [1]
                return [0]

        return _CB()


class CollocationNLP:
    """IPOPT solver for one NLP structure (record, scheme, nodes, with or without band filter).

    What changes between local solves (start and scale of the parameters, state and output
    scales, data, filter coefficients) enters as NLP parameters, so one solver object serves
    every start and every band stage of a run.
    """

    def __init__(self, problem: FitProblem, opts: CasadiCollocationOptions, u: np.ndarray, h: float,
                 m: int, step: float | None, band: bool):
        import casadi as ca

        self.problem, self.opts, self.h, self.band = problem, opts, h, band
        self.hold = problem.hold
        self.u = np.asarray(u, dtype=float)
        self.N = N = self.u.size
        self.step = step
        self.free = problem.free
        self.nm = problem.n_model
        self.names = problem.names
        self.s_u = float(np.max(np.abs(self.u))) or 1.0
        self.v = self.u / self.s_u
        self.degree = 1 if opts.scheme == "trapezoidal" else opts.degree
        self.condensed = opts.formulation == "condensed"
        self.m = m if self.condensed else 1
        self.trans = transition_function(problem.model, self.nm, h, self.degree, opts.scheme, self.hold)
        self.readout = (transition_function(problem.model, self.nm, h, self.degree, opts.scheme, self.hold, step)
                        if step is not None else None)
        self.n = n = self.trans.size_out(0)[0]
        self.q = 1 if self.hold == "zoh" else 2
        self.nf = nf = 4 if band else 0
        self.n_free = n_free = int(self.free.sum())
        params = [q for q, f in zip(problem.parameters, self.free) if f]
        self.log_coords = np.array([q.log_scale and opts.coordinates == "log" for q in params], dtype=bool)

        par = {"theta_ref": ca.MX.sym("theta_ref", len(self.names)), "s_x": ca.MX.sym("s_x", n),
               "s_y": ca.MX.sym("s_y"), "y": ca.MX.sym("y", N)}
        if band:
            par.update(Af=ca.MX.sym("Af", nf, nf), Bf=ca.MX.sym("Bf", nf), Cf=ca.MX.sym("Cf", 1, nf),
                       Df=ca.MX.sym("Df"))
        self.par_names = list(par)
        pvec = ca.veccat(*par.values())
        p = ca.MX.sym("p", n_free)
        theta = self._theta_expr(p, par["theta_ref"])
        thm = theta[: self.nm]
        gain = theta[self.names.index(GAIN)] if GAIN in self.names else 1.0
        states, g, yhat = (self._condensed if self.condensed else self._full)(thm, gain, par)
        e = ca.vec((par["y"].T - yhat) / par["s_y"])
        w = ca.veccat(p, *states)
        self.nx, self.ng = int(w.numel()), int(g.numel())
        nlp = {"x": w, "f": 0.5 * ca.sumsqr(e), "g": g, "p": pvec}
        ipopt = {"linear_solver": "mumps", "sb": "yes", "print_level": self._print_level(),
                 "tol": opts.tol, "max_iter": 100000}  # per-call limits: the iteration callback
        if not self.condensed:
            # MUMPS' automatic scaling of this KKT system reports a singular matrix (measured
            # with n >= 8 states); the NLP is already scaled to order one.
            ipopt.update(mumps_scaling=0, mumps_permuting_scaling=0)
        ipopt.update(opts.ipopt)
        self.log = _IterationLog(self.nx, self.ng, int(pvec.numel()), n_free)
        nlp_opts: dict[str, Any] = {"ipopt": ipopt, "print_time": False, "iteration_callback": self.log}
        if opts.hessian == "gauss-newton":
            J = ca.jacobian(e, w)
            sigma, lam_g = ca.MX.sym("sigma"), ca.MX.sym("lam_g", self.ng)
            H = sigma * ca.triu(ca.mtimes(J.T, J))
            nlp_opts["hess_lag"] = ca.Function(
                "nlp_hess_l", {"x": w, "p": pvec, "lam_f": sigma, "lam_g": lam_g, "hess_gamma_x_x": H},
                ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
        elif opts.hessian == "limited-memory":
            ipopt["hessian_approximation"] = "limited-memory"
        t0 = time.perf_counter()
        self.solver = ca.nlpsol("casadi_collocation", "ipopt", nlp, nlp_opts)
        self.build_time_s = time.perf_counter() - t0
        self._nlp, self._nlp_opts, self._warm_solver = nlp, nlp_opts, None
        self.yhat_fun = ca.Function("yhat", [w, pvec], [yhat])
        self.size = {"variables": self.nx, "constraints": self.ng, "residuals": int(e.numel()),
                     "free_parameters": n_free, "states": n, "state_nodes": self.n_nodes,
                     "samples_per_node": self.m, "collocation_points_per_interval": self.degree,
                     "filter_states": nf}

    # -- symbolic pieces ----------------------------------------------------------------------
    def _print_level(self) -> int:
        if self.opts.print_level is not None:
            return self.opts.print_level
        return 5 if _interactive() else 0

    def _theta_expr(self, p, theta_ref):
        import casadi as ca

        parts, k = [], 0
        for i in range(len(self.names)):
            if self.free[i]:
                parts.append(theta_ref[i] * (ca.exp(p[k]) if self.log_coords[k] else p[k]))
                k += 1
            else:
                parts.append(theta_ref[i])
        return ca.vertcat(*parts)

    def _output_matrices(self, thm, gain, s_x, C, D):
        """Output row and feedthrough, read at t_k - delay when a delay is set."""
        import casadi as ca

        if self.readout is None:
            return C, D * gain
        Phs, Gms, _, _ = self.readout(thm, s_x, self.s_u)
        return ca.mtimes(C, Phs), (ca.mtimes(C, Gms[:, 0]) + D) * gain

    def _condensed(self, thm, gain, par):
        import casadi as ca

        m, n, N, q = self.m, self.n, self.N, self.q
        K = self.n_nodes = int(np.ceil(N / m))
        Phi, Gam, C, D = self.trans(thm, par["s_x"], self.s_u)
        Gam = Gam * gain
        C, D = self._output_matrices(thm, gain, par["s_x"], C, D)
        Dq = ca.horzcat(D, ca.MX.zeros(1, q - 1)) if q > 1 else D
        nz = n
        if self.band:  # cascade model -> filter (input yhat / s_y), one linear system
            Af, Bf, Cf, Df, s_y = par["Af"], par["Bf"], par["Cf"], par["Df"], par["s_y"]
            Phi = ca.vertcat(ca.horzcat(Phi, ca.MX.zeros(n, self.nf)), ca.horzcat(ca.mtimes(Bf, C) / s_y, Af))
            Gam = ca.vertcat(Gam, ca.mtimes(Bf, Dq) / s_y)
            C, Dq = ca.horzcat(Df * C, Cf * s_y), Df * Dq
            nz = n + self.nf
        rows, cols, Pk = [C], [Gam], Phi  # rows[k] = C Phi^k, cols[k] = Phi^k Gam
        for _ in range(1, m):
            rows.append(ca.mtimes(rows[-1], Phi))
            cols.append(ca.mtimes(Phi, cols[-1]))
            Pk = ca.mtimes(Pk, Phi)
        O = ca.vertcat(*rows)  # (m, nz)
        Gm = ca.horzcat(*cols[::-1])  # (nz, q m) acting on [v_jm; ...; v_jm+m-1]
        zero = ca.MX.zeros(1, q)
        T = ca.vertcat(*[
            ca.horzcat(*[ca.mtimes(C, cols[j - 1 - i]) if i < j else (Dq if i == j else zero) for i in range(m)])
            for j in range(m)])
        V = ca.DM(self._input_blocks(K))
        Xi = ca.MX.sym("xi", nz, K)
        Y = ca.mtimes(O, Xi) + ca.mtimes(T, V)  # (m, K): column j = samples jm..jm+m-1
        yhat = ca.reshape(Y, 1, K * m)[:, :N]
        g = ca.vec(Xi[:, 1:] - ca.mtimes(Pk, Xi[:, : K - 1]) - ca.mtimes(Gm, V[:, : K - 1]))
        self.nz = nz
        return [Xi], g, yhat

    def _padded_inputs(self, length: int) -> np.ndarray:
        """(q, length) per-sample inputs [v_k (; v_k+1)], zero after the record (FOH: v_N = v_N-1)."""
        v = np.zeros(length + 1)
        v[: self.N] = self.v
        if self.q == 2:
            v[self.N] = self.v[-1]
            return np.vstack([v[:length], v[1 : length + 1]])
        return v[:length].reshape(1, -1)

    def _input_blocks(self, K: int) -> np.ndarray:
        """(q m, K): column j stacks the inputs of samples jm .. jm+m-1."""
        V = self._padded_inputs(K * self.m)  # (q, K m)
        return V.T.reshape(K, self.m * self.q).T

    def _full(self, thm, gain, par):
        import casadi as ca

        n, N, q, d, h = self.n, self.N, self.q, self.degree, self.h
        self.n_nodes = N
        A, B, C, D = model_matrices_function(self.problem.model, self.nm)(thm, par["s_x"], self.s_u)
        B = B * gain
        C, D = self._output_matrices(thm, gain, par["s_x"], C, D)
        xk, xn, vk = ca.MX.sym("xk", n), ca.MX.sym("xn", n), ca.MX.sym("vk", q)
        Am, Bm = ca.MX.sym("A", n, n), ca.MX.sym("B", n)

        def u_at(tau):
            return vk[0] if q == 1 else vk[0] + tau * (vk[1] - vk[0])

        if self.opts.scheme == "trapezoidal":
            xc = ca.MX.sym("xc", n, 0)
            res = xn - xk - h / 2 * (ca.mtimes(Am, xk + xn) + Bm * (u_at(0.0) + u_at(1.0)))
            self.n_coll = 0
        else:
            tau, Cd, Dc = collocation_matrices(d, self.opts.scheme)
            xc = ca.MX.sym("xc", n, d)
            X = [xk] + [xc[:, j] for j in range(d)]
            res = [sum(Cd[j, r] * X[j] for j in range(d + 1)) - h * (ca.mtimes(Am, X[r]) + Bm * u_at(tau[r]))
                   for r in range(1, d + 1)]
            res = ca.vertcat(*res, sum(Dc[j] * X[j] for j in range(d + 1)) - xn)
            self.n_coll = d
        interval = ca.Function("interval", [xk, xc, xn, vk, Am, Bm], [res])
        intervals = interval.map("intervals", "serial", N - 1, [4, 5], [])  # A, B shared
        Xs = ca.MX.sym("x", n, N)
        Xc = ca.MX.sym("xc", n, self.n_coll * (N - 1))
        Vn = ca.DM(self._padded_inputs(N))
        g = ca.vec(intervals(Xs[:, :-1], Xc, Xs[:, 1:], Vn[:, : N - 1], A, B))
        yhat = ca.mtimes(C, Xs) + D * Vn[0, :]
        states = [Xs, Xc]
        if self.band:
            Af, Bf, Cf, Df, s_y = par["Af"], par["Bf"], par["Cf"], par["Df"], par["s_y"]
            Z = ca.MX.sym("z", self.nf, N)
            r = yhat / s_y
            g = ca.vertcat(g, ca.vec(Z[:, 1:] - ca.mtimes(Af, Z[:, :-1]) - ca.mtimes(Bf, r[:, :-1])))
            yhat = (ca.mtimes(Cf, Z) + Df * r) * s_y
            states.append(Z)
        self.nz = n
        return states, g, yhat

    # -- numerical side -------------------------------------------------------------------------
    def parameter_vector(self, sd: StageData) -> np.ndarray:
        vals = {"theta_ref": sd.theta_ref, "s_x": sd.s_x, "s_y": sd.s_y, "y": sd.y}
        if self.band:
            vals.update(zip(("Af", "Bf", "Cf", "Df"), sd.filt))
        return np.concatenate([np.asarray(vals[k], float).ravel(order="F") for k in self.par_names])

    def _numeric(self, theta: np.ndarray, sd: StageData):
        thm = theta[: self.nm]
        gain = theta[self.names.index(GAIN)] if GAIN in self.names else 1.0
        Phi, Gam, C, D = (np.array(v, dtype=float) for v in self.trans(thm, sd.s_x, self.s_u))
        C, D = C.ravel(), float(D.ravel()[0])
        if self.readout is not None:
            Phs, Gms, _, _ = (np.array(v, dtype=float) for v in self.readout(thm, sd.s_x, self.s_u))
            C, D = C @ Phs, float(C @ Gms.reshape(self.n, -1)[:, 0]) + D
        return Phi, Gam.reshape(self.n, self.q) * gain, C, D * gain

    def warm_start(self, theta: np.ndarray, sd: StageData) -> np.ndarray:
        """NLP variables from a simulation of the collocation model at ``theta`` (a feasible start)."""
        Phi, Gam, C, D = self._numeric(theta, sd)
        length = self.n_nodes * self.m
        V = self._padded_inputs(length)
        X = np.zeros((self.n, length))
        GV = Gam @ V
        for k in range(length - 1):
            X[:, k + 1] = Phi @ X[:, k] + GV[:, k]
        w = [np.where(self.log_coords, 0.0, 1.0)]
        if self.band:
            Af, Bf, _, _ = sd.filt
            Z = filter_states(Af, Bf, (C @ X + D * V[0]) / sd.s_y)
        if self.condensed:
            nodes = X[:, :: self.m]
            if self.band:
                nodes = np.vstack([nodes, Z[:, :: self.m]])
            w.append(nodes.ravel(order="F"))
        else:
            w.append(X.ravel(order="F"))
            if self.n_coll:
                w.append(self._collocation_states(theta, sd, X, V).ravel(order="F"))
            if self.band:
                w.append(Z.ravel(order="F"))
        return np.concatenate(w)

    def simulate_output(self, theta: np.ndarray, sd: StageData) -> np.ndarray:
        """yhat of the collocation model at ``theta`` (the recursion the NLP constrains to)."""
        Phi, Gam, C, D = self._numeric(theta, sd)
        V = self._padded_inputs(self.N)
        GV = Gam @ V
        x, y = np.zeros(self.n), np.zeros(self.N)
        for k in range(self.N):
            y[k] = C @ x + D * V[0, k]
            x = Phi @ x + GV[:, k]
        return y

    def _collocation_states(self, theta, sd: StageData, X, V) -> np.ndarray:
        """(n, d (N-1)) states X_1..X_d of every interval, from the linear collocation equations."""
        n, d, h = self.n, self.degree, self.h
        thm = theta[: self.nm]
        gain = theta[self.names.index(GAIN)] if GAIN in self.names else 1.0
        A, B, _, _ = (np.array(v, dtype=float) for v in
                      model_matrices_function(self.problem.model, self.nm)(thm, sd.s_x, self.s_u))
        B = B.ravel() * gain
        tau, Cd, _ = collocation_matrices(d, self.opts.scheme)
        L = np.kron(Cd[1:, 1:].T, np.eye(n)) - np.kron(np.eye(d), h * A)
        rhs = -np.kron(Cd[0, 1:].reshape(-1, 1), np.eye(n)) @ X[:, :-1]
        for r in range(1, d + 1):
            ur = V[0, :-1] if self.q == 1 else V[0, :-1] + tau[r] * (V[1, :-1] - V[0, :-1])
            rhs[(r - 1) * n : r * n] += h * np.outer(B, ur)
        Xc = np.linalg.solve(L, rhs).reshape(d, n, -1)  # [j, state, interval]
        return Xc.transpose(1, 2, 0).reshape(n, -1)  # column k d + j

    def bounds(self, sd: StageData, lower: np.ndarray, upper: np.ndarray):
        ref = sd.theta_ref[self.free]
        lbx, ubx = np.full(self.nx, -np.inf), np.full(self.nx, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            lo, hi = lower[self.free] / ref, upper[self.free] / ref
            lbx[: self.n_free] = np.where(self.log_coords, np.maximum(np.log(lo), -LOG_RANGE), lo)
            ubx[: self.n_free] = np.where(self.log_coords, np.minimum(np.log(hi), LOG_RANGE), hi)
        first = self.n_free
        lbx[first : first + self.nz] = ubx[first : first + self.nz] = 0.0  # from rest
        if self.band and not self.condensed:
            zs = self.nx - self.nf * self.N
            lbx[zs : zs + self.nf] = ubx[zs : zs + self.nf] = 0.0
        return lbx, ubx

    def warm_solver(self):
        """The solver of a refinement, which starts at (or next to) a minimum found by an earlier
        local solve. With IPOPT's default mu_init = 0.1 the barrier first pushes the parameters
        off that minimum (6e-4 relative in b_sigma measured on a noise-free record, where the
        data term is flat) and a search stage stopped by xtol ends there; the refinement starts
        with mu_init = 1e-9 and so converges onto the minimum. (Everywhere else the default is
        kept: a small mu_init made the exact-Hessian and full formulations end elsewhere on the
        Table 3.1 record, and band stages of the SLS chain wander.)"""
        if self._warm_solver is None:
            import casadi as ca

            opts = dict(self._nlp_opts)
            opts["ipopt"] = {"mu_init": 1e-9, **self._nlp_opts["ipopt"]}
            t0 = time.perf_counter()
            self._warm_solver = ca.nlpsol("casadi_collocation_warm", "ipopt", self._nlp, opts)
            self.build_time_s += time.perf_counter() - t0
        return self._warm_solver

    def solve(self, sd: StageData, lower, upper, max_iter: int, xtol: float | None, ftol: float | None,
              warm: bool = False):
        """Run IPOPT from ``sd.x0``; returns (theta, stats, w, objective, trace records, stop reason).

        ``max_iter`` and ``xtol`` (relative parameter step, search stages) are enforced by the
        iteration callback, so one solver object serves every stage."""
        lbx, ubx = self.bounds(sd, lower, upper)
        self.log.reset(max_iter, xtol, ftol)
        solver = self.warm_solver() if warm else self.solver
        sol = solver(x0=np.clip(sd.x0, lbx, ubx), p=self.parameter_vector(sd), lbx=lbx, ubx=ubx,
                     lbg=0.0, ubg=0.0)
        stats = solver.stats()
        w = np.array(sol["x"], dtype=float).ravel()
        theta = sd.theta_ref.copy()
        theta[self.free] = self.free_values(sd.theta_ref[self.free], w[: self.n_free])
        # IPOPT relaxes bounds by ~1e-8 (bound_relax_factor): project onto the exact bounds
        theta = np.clip(theta, lower, upper)
        records = []
        for f, pv in self.log.records:
            th = sd.theta_ref.copy()
            th[self.free] = self.free_values(sd.theta_ref[self.free], pv)
            records.append((f * sd.s_y**2, th))
        return theta, stats, w, float(sol["f"]) * sd.s_y**2, records, self.log.stop_reason

    def free_values(self, ref: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Free parameters from NLP coordinates: ref e^z (log-scale parameters) or ref z."""
        return np.where(self.log_coords, ref * np.exp(np.where(self.log_coords, z, 0.0)), ref * z)

    def prediction(self, w: np.ndarray, sd: StageData) -> np.ndarray:
        return np.array(self.yhat_fun(w, self.parameter_vector(sd)), dtype=float).ravel()


def _interactive() -> bool:
    """IPOPT prints its iterations when stdout is a terminal (and not in CI)."""
    try:
        return bool(sys.stdout.isatty()) and not os.environ.get("CI")
    except (AttributeError, ValueError):
        return False


# ---------------------------------------------------------------------------------------------
# the solver
# ---------------------------------------------------------------------------------------------
def _stats_summary(stats: dict) -> dict:
    """IPOPT statistics as plain JSON-able values (the per-iteration arrays summarised)."""
    out = {k: (v if isinstance(v, (bool, str)) else float(v) if isinstance(v, float) else int(v))
           for k, v in stats.items() if isinstance(v, (bool, str, int, float))}
    it = stats.get("iterations") or {}
    if it.get("obj"):
        out["final_inf_pr"] = float(it["inf_pr"][-1])
        out["final_inf_du"] = float(it["inf_du"][-1])
    return out


class _Session:
    """Everything one ``solve`` shares between its local solves (NLPs are built once)."""

    def __init__(self, problem: FitProblem, opts: CasadiCollocationOptions):
        from mbus_framework.estimation.nuisance import _split_delay

        self.problem, self.opts = problem, opts
        self.h = problem.dt
        delay = float(problem.fixed.get(DELAY, 0.0)) if DELAY in problem.names else 0.0
        self.shift, self.step = _split_delay(delay, self.h) if delay > 0 else (0, None)
        self.n_pred = problem.y.size - self.shift
        if self.n_pred < 2:
            raise EstimationError("casadi_collocation: the delay leaves fewer than 2 samples to fit")
        self.u = problem.u[: self.n_pred]
        self.s_y = float(np.sqrt(np.mean(problem.y**2))) or 1.0
        self.nlps: dict[bool, CollocationNLP] = {}
        self.m: int | None = None
        self.nfev = self.njev = 0
        self.last: dict[str, Any] = {}
        self.log: list[dict[str, Any]] = []  # one entry per local solve
        self.results: list[np.ndarray] = []  # estimates of earlier local solves (warm starts)

    # -- structure --------------------------------------------------------------------------------
    def samples_per_node(self, theta: np.ndarray) -> int:
        o = self.opts
        if o.samples_per_node != "auto":
            return int(min(o.samples_per_node, self.n_pred))
        A = as_float_ss(self.problem.model.state_space(theta[: self.problem.n_model])).A
        rate = float(np.max(np.abs(np.linalg.eigvals(A)))) * self.h
        m = int(o.node_phase / rate) if rate > 0 else 64
        return int(np.clip(m, 1, min(64, self.n_pred)))

    def nlp(self, band: bool, theta: np.ndarray) -> CollocationNLP:
        if band not in self.nlps:
            if self.m is None:
                self.m = self.samples_per_node(theta)
            self.nlps[band] = CollocationNLP(self.problem, self.opts, self.u, self.h, self.m, self.step, band)
        return self.nlps[band]

    # -- scaling --------------------------------------------------------------------------------
    def state_scales(self, theta: np.ndarray) -> np.ndarray:
        """max_k |x_i(t_k)| of a simulation (exact discretisation) at ``theta``."""
        p = self.problem
        model_theta, gain, _ = p.split(theta)
        sys_d = discretize(p.model.state_space(model_theta), self.h, p.hold)
        x = np.zeros(sys_d.Phi.shape[0])
        peak = np.zeros_like(x)
        Gu = np.outer(sys_d.Gamma, gain * self.u)
        for k in range(self.n_pred - 1):
            x = sys_d.Phi @ x + Gu[:, k]
            np.maximum(peak, np.abs(x), out=peak)
        good = np.isfinite(peak) & (peak > 0)
        if not good.any():
            return np.ones_like(peak)
        peak[~good] = float(np.exp(np.mean(np.log(peak[good]))))
        return peak

    # -- one local solve -------------------------------------------------------------------------
    def local_fit(self, problem: FitProblem, theta0: np.ndarray, band: BandFilter | None, max_nfev: int,
                  final: bool) -> LocalResult:
        p, o = self.problem, self.opts
        theta0 = np.clip(np.asarray(theta0, dtype=float), problem.lower, problem.upper)
        typical = np.array([q.typical for q in p.parameters], dtype=float)
        # free parameters are scaled by their start (by ``typical`` when the start is zero);
        # fixed ones enter with their value
        zero = p.free & ~(np.abs(theta0) > 0)
        ref = np.where(zero, np.where(typical != 0, typical, 1.0), theta0)
        nlp = self.nlp(band is not None, ref)
        y = p.y
        filt = None
        if band is not None:
            Af, Bf, Cf, Df = butterworth_ss(band.cutoff_hz, self.h)
            s_z = np.max(np.abs(filter_states(Af, Bf, y / self.s_y)), axis=1)
            s_z[~(s_z > 0)] = 1.0
            filt = (Af * np.outer(1 / s_z, s_z), Bf / s_z, Cf * s_z, Df)
            y = filter_data(Af, Bf, Cf, Df, y / self.s_y) * self.s_y
        with np.errstate(over="ignore", invalid="ignore"):
            sd = StageData(ref, self.state_scales(ref), self.s_y, y[self.shift:], filt)
            sd.x0 = nlp.warm_start(ref, sd)
        if not np.all(np.isfinite(sd.x0)):  # the model cannot be simulated here: a failed stage
            self.log.append({"band_hz": None if band is None else band.cutoff_hz, "final": final,
                             "iterations": 0, "status": "simulation at the start is not finite",
                             "cost": np.inf, "wall_time_s": 0.0})
            return LocalResult(theta=theta0, cost=np.inf, nfev=0, njev=0, status=-1,
                               message="casadi_collocation: the start cannot be simulated (non-finite states)",
                               iterations=0, trace=[])
        max_iter = o.max_iter if final else max_nfev
        # the refinement of an earlier local solve's result starts at or next to a minimum
        warm = final and any(np.array_equal(theta0, r) for r in self.results)
        t0 = time.perf_counter()
        # the problem's own bounds (the user's), not the strategy's search region: finite region
        # bounds on the NLP variables make IPOPT's barrier creep along flat valleys (a Maxwell
        # series spring running to the bound); the region bounds the starts only
        theta, stats, w, fobj, records, reason = nlp.solve(sd, p.lower, p.upper, max_iter,
                                                           *((o.xtol, o.ftol) if final else (o.stage_xtol, o.stage_ftol)),
                                                           warm=warm)
        self.results.append(theta)
        wall = time.perf_counter() - t0
        ret = str(stats.get("return_status"))
        if ret == "User_Requested_Stop":
            status, message = (4 if reason.startswith("relative") else 0), f"IPOPT stopped: {reason}"
        else:
            status, message = IPOPT_STATUS.get(ret, -1), f"IPOPT: {ret}"
        if band is None:
            with np.errstate(over="ignore", invalid="ignore"):
                r = p.y - p.predict(theta)
            cost = 0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf
        else:
            cost = fobj
        nfev, njev = int(stats.get("n_call_nlp_f", 0)), int(stats.get("n_call_nlp_jac_g", 0))
        self.nfev, self.njev = self.nfev + nfev, self.njev + njev
        trace = [{"iteration": i, "cost": c, "theta": th.tolist()} for i, (c, th) in enumerate(records)]
        self.last = {"nlp": nlp, "stage_data": sd, "w": w, "stats": stats, "objective": fobj,
                     "solve_time_s": wall, "band": band is not None, "theta": theta}
        self.log.append({"band_hz": None if band is None else band.cutoff_hz, "final": final, "warm": warm,
                         "iterations": int(stats.get("iter_count", 0)), "status": ret if not reason else reason,
                         "cost": cost, "wall_time_s": wall})
        return LocalResult(theta=theta, cost=cost, nfev=nfev, njev=njev, status=status, message=message,
                           iterations=int(stats.get("iter_count", 0)), trace=trace)

    def start(self) -> tuple[np.ndarray, str]:
        p = self.problem
        if p.initial is not None:
            theta0, source = p.full(np.asarray(p.initial, float)[p.free], p.initial), "config"
        else:
            guess = p.default_initial()
            theta0, source = p.full(np.asarray(guess, float)[p.free], guess), "model.initial_guess"
        return np.clip(theta0, p.lower, p.upper), source


def _truncated(problem: FitProblem, n: int) -> FitProblem:
    """The same problem on the first ``n`` samples (the dynamics still start from rest)."""
    return replace(problem, t=problem.t[:n], u=problem.u[:n], y=problem.y[:n],
                   lower=problem.lower, upper=problem.upper)


class CasadiCollocation(Solver):
    """Direct collocation (states as NLP variables) solved by IPOPT, inside the global strategy."""

    Options = CasadiCollocationOptions
    summary = "CasADi direct collocation (Legendre/Radau/trapezoidal) solved by IPOPT, Gauss-Newton Hessian"

    def solve(self, problem: FitProblem, progress: Progress | None = None) -> FitResult:
        import casadi as ca

        t0 = time.perf_counter()
        o = self.options
        _check_supported(problem)
        session = _Session(problem, o)
        nfev = njev = 0
        search_log: list[dict[str, Any]] = []
        if o.global_search:
            n_search = o.search_samples
            if n_search is not None and n_search < problem.y.size:
                sproblem = _truncated(problem, n_search)
                ssession = _Session(sproblem, o)
                found, report, nfev, njev = search(sproblem, ssession.local_fit, o.strategy, progress)
                search_log = [dict(r, samples=n_search) for r in ssession.log]
                session.results.append(np.clip(found.theta, problem.lower, problem.upper))  # a warm start
                best = session.local_fit(problem, found.theta, None, o.max_iter, True)
                best.trace = found.trace + [dict(r, stage="refinement (whole record)") for r in best.trace]
                nfev, njev = nfev + best.nfev, njev + best.njev
            else:
                best, report, nfev, njev = search(problem, session.local_fit, o.strategy, progress)
            strategy = report.as_dict()
        else:
            theta0, source = session.start()
            if progress:
                progress.start("IPOPT", total=1)
            best = session.local_fit(problem, theta0, None, o.max_iter, True)
            if progress:
                progress.advance(1, f"cost {best.cost:.4g}")
                progress.stop()
            nfev, njev = best.nfev, best.njev
            strategy = {"initial_source": source, "initial": dict(zip(problem.names, map(float, theta0))),
                        "global_search": False}
        last = session.last
        extras = {"method": "ipopt", "scheme": o.scheme, "degree": 1 if o.scheme == "trapezoidal" else o.degree,
                  "formulation": o.formulation, "coordinates": o.coordinates, "hessian": o.hessian}
        result = FitResult.at_estimate(problem, best, nfev=nfev, njev=njev, wall_time_s=0.0,
                                       strategy=strategy, extras=extras)
        yhat = problem.y - result.residuals
        nlp = session.nlps.get(False)
        if nlp is not None and last and not last["band"]:
            sd = replace(last["stage_data"], s_x=session.state_scales(best.theta))
            ycoll = nlp.simulate_output(best.theta, sd)
            yex = yhat[session.shift:]
            extras.update(
                nlp_size=nlp.size,
                nlp_build_time_s=nlp.build_time_s,
                ipopt=_stats_summary(last["stats"]),
                ipopt_solve_time_s=last["solve_time_s"],
                collocation_cost=0.5 * float(np.sum((problem.y[session.shift:] - ycoll) ** 2)
                                             + np.sum(problem.y[: session.shift] ** 2)),
                discretisation_error=float(np.linalg.norm(ycoll - yex) / max(np.linalg.norm(yex), 1e-300)),
            )
        if last and not np.array_equal(last["theta"], best.theta):
            # the strategy keeps a search-stage result when the refinement did not lower the cost
            extras["note"] = "the refinement did not lower the cost; IPOPT figures describe the refinement"
        extras["local_solves"] = search_log + session.log
        extras["casadi_version"] = ca.__version__
        result.wall_time_s = time.perf_counter() - t0
        return result


def _check_supported(problem: FitProblem) -> None:
    if problem.output_filter is not None:
        raise EstimationError(
            "casadi_collocation: a compensator with a model-side output filter (a spectral filter of the "
            "prediction) cannot enter the collocation NLP; use solver scipy_lm for this compensator"
        )
    if DELAY in problem.names and problem.free[problem.names.index(DELAY)]:
        raise EstimationError(
            "casadi_collocation: estimating a delay is not supported (its whole-sample part is not "
            "differentiable); fix nuisance.delay or use solver scipy_lm"
        )
    if problem.hold not in ("zoh", "foh"):
        raise EstimationError(f"casadi_collocation: unknown hold {problem.hold!r}")


@hookimpl
def mbus_solvers():
    return [SolverSpec("casadi_collocation", CasadiCollocation, CasadiCollocation.summary)]
