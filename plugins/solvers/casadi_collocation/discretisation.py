"""Collocation coefficients, stability functions and the symbolic (CasADi) transition of one sample interval."""
from __future__ import annotations

import numpy as np


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
