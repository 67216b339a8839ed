"""Exact discretisation (Van Loan) and the kernels of eq. (1) by repeated doubling.

The safe path of :mod:`mbus_framework.engine.simulation` (eq. (1) and the notation are
defined there). With Phi = e^{A h} and h = ``dt`` [s],

    Gamma0 = int_0^h e^{A s} ds B = h phi_1(A h) B,   Gamma1 = int_0^h e^{A s} (1 - s/h) ds B = h phi_2(A h) B,

all from one matrix exponential of an augmented matrix (Van Loan, 1978). The Krylov sequence
[v, Phi v, Phi^2 v, ...] is formed by doubling, [S, Phi^(2^j) S]. It needs no
eigendecomposition and is exact for defective (repeated-eigenvalue, Jordan-block) models.
Only the states a later doubling level reads are formed (a third to a half of them); the
kernel values beyond are projections (C Phi^f) (Phi^k v). Cost O(n^2 N).

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


def doubling_schedule(count: int) -> tuple[list[tuple[int, int]], int]:
    """Levels (filled, take) of repeated doubling up to ``count`` terms, and the number of
    leading terms any level reads (``need``): level (f, t) forms terms f..f+t-1 from terms
    0..t-1 and Phi^f."""
    levels, filled = [], 1
    while filled < count:
        take = min(filled, count - filled)
        levels.append((filled, take))
        filled += take
    return levels, max((t for _, t in levels), default=1)


def krylov_outputs(Phi: np.ndarray, v: np.ndarray, c: np.ndarray, count: int) -> np.ndarray:
    """c Phi^k v for k < count (count,), by doubling.

    Only the states Phi^k v that a later level reads are formed (k < ``need``, between a third
    and a half of ``count``); their outputs are c (Phi^k v), and the terms of a level (f, t)
    beyond them are the projections c Phi^(f+k) v = (c Phi^f) (Phi^k v), n flops each.
    """
    out = np.empty(count)
    if count == 0:
        return out
    levels, need = doubling_schedule(count)
    S = np.empty((need, v.shape[0]))  # row k = (Phi^k v)^T
    S[0] = v
    PT = Phi.T
    for i, (filled, take) in enumerate(levels):
        head = S[:take]
        full = min(max(need - filled, 0), take)
        if full:
            S[filled : filled + full] = small_matmul(head[:full], PT)
        if full < take:  # small calls, see small_matmul
            out[filled + full : filled + take] = small_matmul(head[full:], (c @ PT.T)[:, None])[:, 0]
        if i + 1 < len(levels):
            PT = small_matmul(PT, PT, rows=32)
    out[:need] = small_matmul(S, c[:, None])[:, 0]
    return out


def krylov_sensitivity_outputs(Phi, Psi, v, dv, c, dc, count):
    """Outputs of the doubling sensitivity recursion: for k < count,

        o[k] = c Phi^k v,    o_i[k] = dc_i Phi^k v + c ((d Phi^k)_i v + Phi^k dv_i),

    returned as o (count,) and o_p (p, count), using [[P, 0], [Q, P]]^2 = [[P^2, 0], [QP + PQ, P^2]]
    (P = Phi^f, Q_i = (d Phi^f)_i at level f). As in :func:`krylov_outputs`, only the states
    s_k = Phi^k v, ds_{i,k} that a later level reads are formed; the terms of a level beyond
    them are the projections

        o[f+k] = (c P) s_k,   o_i[f+k] = (dc_i P + c Q_i) s_k + (c P) ds_{i,k}.
    """
    n, p = v.shape[0], dv.shape[0]
    o = np.empty(count)
    op = np.empty((p, count))
    if count == 0:
        return o, op
    levels, need = doubling_schedule(count)
    s = np.empty((need, n))
    ds = np.empty((p, need, n))
    s[0] = v
    ds[:, 0] = dv
    P, Q = Phi, Psi
    for i, (filled, take) in enumerate(levels):
        s_head, ds_head = s[:take], ds[:, :take]
        full = min(max(need - filled, 0), take)
        if full:
            ds[:, filled : filled + full] = small_matmul(s_head[:full], Q.transpose(0, 2, 1)) + small_matmul(ds_head[:, :full], P.T)
            s[filled : filled + full] = small_matmul(s_head[:full], P.T)
        if full < take:
            cP = c @ P  # (n,)
            row = dc @ P + np.einsum("m,pmn->pn", c, Q)  # (p, n): dc_i P + c Q_i
            # stacks of small products (see small_matmul): s_k [c P, dc_i P + c Q_i] and ds_{i,k} (c P)
            both = small_matmul(s_head[full:], np.concatenate([cP[:, None], row.T], axis=1))  # (take - full, 1 + p)
            o[filled + full : filled + take] = both[:, 0]
            op[:, filled + full : filled + take] = both[:, 1:].T + small_matmul(ds_head[:, full:], cP[:, None])[..., 0]
        if i + 1 < len(levels):
            Q = small_matmul(Q, P, rows=32) + small_matmul(P, Q, rows=32)
            P = small_matmul(P, P, rows=32)
    both = small_matmul(s, np.concatenate([c[:, None], dc.T], axis=1))  # (need, 1 + p)
    o[:need] = both[:, 0]
    op[:, :need] = both[:, 1:].T + small_matmul(ds, c[:, None])[..., 0]
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
