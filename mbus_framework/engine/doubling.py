"""Exact discretisation (Van Loan) and the kernels of eq. (1) by repeated doubling.

The safe path of :mod:`mbus_framework.engine.simulation` (eq. (1) and the notation are
defined there). With Phi = e^{A h} and h = ``dt`` [s],

    Gamma0 = int_0^h e^{A s} ds B = h phi_1(A h) B,   Gamma1 = int_0^h e^{A s} (1 - s/h) ds B = h phi_2(A h) B,

all from one matrix exponential of an augmented matrix (Van Loan, 1978). It needs no
eigendecomposition and is exact for defective (repeated-eigenvalue, Jordan-block) models.
The kernel values C Phi^k v, k = a K + b with K ~ sqrt(N), are (C Phi^(aK)) (Phi^b v): the
K states [v, Phi v, ...] and the A ~ sqrt(N) rows [C, C Phi^K, ...] come by repeated
doubling ([S, Phi^(2^j) S]), the N values from one (A, n) x (n, K) product. Cost
O(n^2 sqrt(N) + n N + n^3 log N).

Sensitivities: the forward-sensitivity system [[A, 0], [A_p, A]] (2n states) is discretised
per parameter; its exact discretisation is the exact derivative of the discretised model.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.linalg import expm

from mbus_framework.engine.small_products import small_matmul
from mbus_framework.interfaces.model import StateSpace

Hold = Literal["zoh", "foh"]


@dataclass(frozen=True)
class DiscreteSystem:
    """x[k+1] = Phi x[k] + Gamma u[k],  y[k] = C x[k] + D u[k]  (effective form for FOH).

    For FOH, ``Gamma`` is Gamma_eff = Gamma0 - Gamma1 + Phi Gamma1, ``D`` is D + C Gamma1 and
    ``Gamma1`` = h phi_2(A h) B is kept: from rest the effective state starts at
    -Gamma1 u[0], which adds -u[0] C Phi^k Gamma1 to y[k] (eq. (1) of :mod:`mbus_framework.engine.simulation`).
    ``Gamma1`` is None for ZOH.
    """

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    D: float
    Gamma1: np.ndarray | None = None


def as_float_ss(ss: StateSpace) -> StateSpace:
    """The model's matrices as 2-D float64 arrays."""
    return StateSpace(*(np.atleast_2d(np.asarray(m, dtype=float)) for m in ss))


def discretize(ss: StateSpace, dt: float, hold: Hold = "zoh") -> DiscreteSystem:
    """Exact discretisation of a continuous SISO system for sample interval ``dt`` [s].

    ZOH: expm([[A h, B h], [0, 0]]) = [[Phi, Gamma0], [0, 1]].
    FOH: expm([[A h, B h, 0], [0, 0, 1], [0, 0, 0]]) holds Phi, Gamma0 = h phi_1(Ah) B and
    Gamma1 = h phi_2(Ah) B (Van Loan, 1978).
    """
    check_hold(hold)
    A, B, C, D = as_float_ss(ss)
    n = A.shape[0]
    if hold == "zoh":
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = A * dt
        M[:n, n:] = B * dt
        E = expm(M)
        return DiscreteSystem(E[:n, :n], E[:n, n], C[0], float(D[0, 0]))
    M = np.zeros((n + 2, n + 2))
    M[:n, :n] = A * dt
    M[:n, n : n + 1] = B * dt
    M[n, n + 1] = 1.0
    E = expm(M)
    Phi, G0, G1 = E[:n, :n], E[:n, n], E[:n, n + 1]
    return DiscreteSystem(Phi, G0 - G1 + Phi @ G1, C[0], float(D[0, 0] + C[0] @ G1), G1)


def markov_parameters(sys: DiscreteSystem, count: int) -> np.ndarray:
    """g[0..count-1]: g[0] = D, g[m] = C Phi^(m-1) Gamma (repeated doubling)."""
    g = np.empty(count)
    if count == 0:
        return g
    g[0] = sys.D
    if count > 1:
        g[1:] = krylov_outputs(sys.Phi, sys.Gamma, sys.C, count - 1)
    return g


def split_lags(count: int) -> tuple[int, int]:
    """Baby and giant step counts (K, A) for lags k = a K + b < count (b < K, a < A): K the
    power of two at most sqrt(count), A = ceil(count / K)."""
    if count <= 1:
        return 1, count
    K = 1 << (int(np.sqrt(count)).bit_length() - 1)
    return K, -(-count // K)


def power_rows(x: np.ndarray, dx: np.ndarray | None, M: np.ndarray, dM: np.ndarray | None, count: int,
               power: bool = True):
    """Rows x M^k for k < count (count, n) by doubling, with their derivatives
    dx_i M^k + x (d M^k)_i (p, count, n) when ``dx`` (p, n) and ``dM`` (p, n, n) are given.

    Level t forms rows t..2t-1 from rows 0..t-1 and M^t, d(M^t); then
    M^(2t) = M^t M^t, d(M^(2t)) = d(M^t) M^t + M^t d(M^t) ([[P, 0], [Q, P]]^2 =
    [[P^2, 0], [QP + PQ, P^2]]). Returns the rows, their derivatives (or None) and, with
    ``power``, M^T, d(M^T) with T the smallest power of two >= count (else None, None).
    """
    n = x.shape[0]
    X = np.empty((count, n))
    X[0] = x
    dX = None
    if dx is not None:
        dX = np.empty((dx.shape[0], count, n))
        dX[:, 0] = dx
    t = 1
    while t < count:
        take = min(t, count - t)
        if dX is not None:
            dX[:, t : t + take] = small_matmul(dX[:, :take], M) + small_matmul(X[:take], dM)
        X[t : t + take] = small_matmul(X[:take], M)
        t *= 2
        if power or t < count:
            if dM is not None:
                dM = small_matmul(dM, M, rows=32) + small_matmul(M, dM, rows=32)
            M = small_matmul(M, M, rows=32)
    return (X, dX, M, dM) if power else (X, dX, None, None)


def krylov_outputs(Phi: np.ndarray, v: np.ndarray, c: np.ndarray, count: int) -> np.ndarray:
    """c Phi^k v for k < count (count,), by baby and giant steps.

    With k = a K + b (:func:`split_lags`, K ~ sqrt(count)): c Phi^k v = (c Phi^(aK)) (Phi^b v).
    The K states Phi^b v and the A rows c Phi^(aK) come by doubling (:func:`power_rows`), the
    outputs from one (A, n) x (n, K) product: O(n^2 sqrt(count) + n count) flops, and every
    output is a product of at most log2(count) + 1 computed powers of Phi.
    """
    if count == 0:
        return np.empty(0)
    K, A = split_lags(count)
    S, _, PK, _ = power_rows(v, None, Phi.T, None, K)  # rows (Phi^b v)^T; (Phi^K)^T
    rows, _, _, _ = power_rows(c, None, PK.T, None, A, power=False)  # rows c Phi^(aK)
    return small_matmul(rows, S.T).reshape(-1)[:count]


def krylov_sensitivity_outputs(Phi, Psi, v, dv, c, dc, count):
    """Outputs of the doubling sensitivity recursion: for k < count,

        o[k] = c Phi^k v,    o_i[k] = dc_i Phi^k v + c ((d Phi^k)_i v + Phi^k dv_i),

    returned as o (count,) and o_p (p, count); Psi_i = (d Phi)_i. As in :func:`krylov_outputs`,
    k = a K + b: with the states s_b = Phi^b v, ds_{i,b} = (d Phi^b)_i v + Phi^b dv_i and the
    rows l_a = c Phi^(aK), m_{i,a} = dc_i Phi^(aK) + c (d Phi^(aK))_i (all by doubling),

        o[aK + b] = l_a s_b,    o_i[aK + b] = m_{i,a} s_b + l_a ds_{i,b}.
    """
    p = dv.shape[0]
    if count == 0:
        return np.empty(0), np.empty((p, 0))
    K, A = split_lags(count)
    S, dS, PK, QK = power_rows(v, dv, Phi.T, Psi.transpose(0, 2, 1), K)
    L, dL, _, _ = power_rows(c, dc, PK.T, QK.transpose(0, 2, 1), A, power=False)
    ST = S.T
    o = small_matmul(L, ST).reshape(-1)[:count]
    op = (small_matmul(dL, ST) + small_matmul(L, dS.transpose(0, 2, 1))).reshape(p, -1)[:, :count]
    return o, op


def doubling_kernels(ss: StateSpace, dt: float, hold: Hold, N: int, derivs=None):
    """Kernels g (1+p, N) and, for FOH, c (1+p, N) of eq. (1) by Van Loan + doubling."""
    base = discretize(ss, dt, hold)
    p = 0 if derivs is None else len(derivs)
    g = np.empty((1 + p, N))
    corr = np.empty((1 + p, N)) if hold == "foh" else None
    if N == 0:
        return g, corr
    if p == 0:
        g[0] = markov_parameters(base, N)
        if corr is not None:
            corr[0] = krylov_outputs(base.Phi, base.Gamma1, base.C, N)
        return g, corr
    A, B, C, _ = ss
    n = A.shape[0]
    Psi = np.empty((p, n, n))
    dGamma = np.empty((p, n))
    dGamma1 = np.empty((p, n))
    dC = np.empty((p, n))
    dD = np.empty(p)
    for i, d in enumerate(derivs):
        aug = StateSpace(
            np.block([[A, np.zeros((n, n))], [np.asarray(d.A, float), A]]),
            np.vstack([B, np.asarray(d.B, float)]),
            np.hstack([np.asarray(d.C, float), C]),
            np.asarray(d.D, float),
        )
        da = discretize(aug, dt, hold)
        Psi[i] = da.Phi[n:, :n]
        dGamma[i] = da.Gamma[n:]
        dC[i] = da.C[:n]
        dD[i] = da.D  # FOH: D_p + C_p Gamma1 + C dGamma1, the derivative of D + C Gamma1
        if hold == "foh":
            dGamma1[i] = da.Gamma1[n:]
    g[0, 0], g[1:, 0] = base.D, dD
    if N > 1:
        g[0, 1:], g[1:, 1:] = krylov_sensitivity_outputs(base.Phi, Psi, base.Gamma, dGamma, base.C, dC, N - 1)
    if corr is not None:
        corr[0], corr[1:] = krylov_sensitivity_outputs(base.Phi, Psi, base.Gamma1, dGamma1, base.C, dC, N)
    return g, corr


def check_hold(hold) -> None:
    if hold not in ("zoh", "foh"):
        raise ValueError(f"hold must be 'zoh' or 'foh', not {hold!r}")
