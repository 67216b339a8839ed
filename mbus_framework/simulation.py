"""Exact discrete-time simulation of a medium model and its parameter sensitivities.

For a sampled input u[k] (sample interval h) the continuous model is discretised exactly

    zero-order hold (u constant over [kh, (k+1)h)):
        Phi = e^{A h},  Gamma = int_0^h e^{A s} ds B
    first-order hold (u linear between samples, as python-control's forced_response):
        the same with Gamma_eff = Gamma0 - Gamma1 + Phi Gamma1, D_eff = D + C Gamma1,
        Gamma1 = int_0^h e^{A (h - s)} (s / h) ds B

both from one matrix exponential of an augmented matrix (Van Loan). The response from rest is
the causal convolution y = g * u with the Markov parameters g[0] = D, g[m] = C Phi^(m-1) Gamma.
The Markov parameters come from repeated doubling, [S, Phi^(2^j) S], which needs no
eigendecomposition and is therefore exact for defective (repeated-eigenvalue) models too;
the convolution is an FFT product. Cost: O(n_states^2 N) + O(N log N).

Sensitivities dy/dtheta_i are the output of the forward-sensitivity system

    d/dt [z; z_i] = [[A, 0], [A_i, A]] [z; z_i] + [B; B_i] u,   y_i = C_i z + C z_i + D_i u

(A_i = dA/dtheta_i, ...), which is itself linear; its exact discretisation is the exact
derivative of the discretised model. A_i, B_i, C_i, D_i come from complex-step
differentiation of the model's own ``state_space`` (no model-specific code).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import fft as sfft
from scipy.linalg import expm

from .model import MediumModel, StateSpace

Hold = Literal["zoh", "foh"]


@dataclass(frozen=True)
class DiscreteSystem:
    """x[k+1] = Phi x[k] + Gamma u[k],  y[k] = C x[k] + D u[k]  (effective form for FOH)."""

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    D: float


def as_float_ss(ss: StateSpace) -> StateSpace:
    return StateSpace(*(np.atleast_2d(np.asarray(m, dtype=float)) for m in ss))


def discretize(ss: StateSpace, dt: float, hold: Hold = "zoh") -> DiscreteSystem:
    """Exact discretisation of a continuous single-input single-output system."""
    A, B, C, D = as_float_ss(ss)
    n = A.shape[0]
    if hold == "zoh":
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = A * dt
        M[:n, n:] = B * dt
        E = expm(M)
        return DiscreteSystem(E[:n, :n], E[:n, n], C[0], float(D[0, 0]))
    if hold == "foh":
        M = np.zeros((n + 2, n + 2))
        M[:n, :n] = A * dt
        M[:n, n : n + 1] = B * dt
        M[n, n + 1] = 1.0
        E = expm(M)
        Phi, G0, G1 = E[:n, :n], E[:n, n], E[:n, n + 1]
        return DiscreteSystem(Phi, G0 - G1 + Phi @ G1, C[0], float(D[0, 0] + C[0] @ G1))
    raise ValueError(f"hold must be 'zoh' or 'foh', not {hold!r}")


def markov_parameters(sys: DiscreteSystem, count: int) -> np.ndarray:
    """g[0..count-1]: g[0] = D, g[m] = C Phi^(m-1) Gamma (repeated doubling)."""
    g = np.empty(count)
    g[0] = sys.D
    if count > 1:
        g[1:] = sys.C @ _krylov_columns(sys.Phi, sys.Gamma, count - 1)
    return g


def _krylov_columns(Phi: np.ndarray, v: np.ndarray, count: int) -> np.ndarray:
    """[v, Phi v, Phi^2 v, ..., Phi^(count-1) v] as columns, by doubling."""
    S = v.reshape(-1, 1)
    P = Phi
    while S.shape[1] < count:
        S = np.hstack([S, P @ S[:, : count - S.shape[1]]])
        if S.shape[1] < count:
            P = P @ P
    return S


def causal_convolve(g: np.ndarray, u: np.ndarray) -> np.ndarray:
    """y[k] = sum_{j<=k} g[k-j] u[j] for k < N; g may carry leading batch axes."""
    N = u.shape[-1]
    nfft = sfft.next_fast_len(2 * N - 1, real=True)
    G = sfft.rfft(g, nfft, axis=-1)
    U = sfft.rfft(u, nfft, axis=-1)
    return sfft.irfft(G * U, nfft, axis=-1)[..., :N]


def simulate_ss(ss: StateSpace, u: np.ndarray, dt: float, hold: Hold = "zoh") -> np.ndarray:
    """Output from rest of a continuous SISO system for samples ``u`` at interval ``dt``."""
    u = np.asarray(u, dtype=float)
    return causal_convolve(markov_parameters(discretize(ss, dt, hold), u.shape[-1]), u)


def simulate(model: MediumModel, theta, u: np.ndarray, dt: float, hold: Hold = "zoh") -> np.ndarray:
    """Model output y [N] for input force u [N] sampled at ``dt`` [s], from rest."""
    return simulate_ss(model.state_space(np.asarray(theta, dtype=float)), u, dt, hold)


def state_space_derivatives(model: MediumModel, theta) -> list[StateSpace]:
    """dA/dtheta_i, dB/dtheta_i, dC/dtheta_i, dD/dtheta_i by complex step (exact to round-off)."""
    theta = np.asarray(theta, dtype=float)
    out = []
    for i in range(theta.size):
        step = 1e-20 * max(abs(theta[i]), 1e-300)
        tc = theta.astype(complex)
        tc[i] += 1j * step
        ss = model.state_space(tc)
        out.append(StateSpace(*(np.atleast_2d(np.imag(np.asarray(m, dtype=complex))) / step for m in ss)))
    return out


def simulate_with_sensitivities(
    model: MediumModel, theta, u: np.ndarray, dt: float, hold: Hold = "zoh"
) -> tuple[np.ndarray, np.ndarray]:
    """Output y (N,) and exact sensitivities dy/dtheta (N, p) of the discretised model."""
    theta = np.asarray(theta, dtype=float)
    u = np.asarray(u, dtype=float)
    N = u.shape[-1]
    ss = as_float_ss(model.state_space(theta))
    n = ss.A.shape[0]
    derivs = state_space_derivatives(model, theta)
    p = len(derivs)
    base = discretize(ss, dt, hold)
    # Per-parameter augmented discretisation: lower-left block Psi_i, lower input block.
    Psi = np.empty((p, n, n))
    dGamma = np.empty((p, n))
    dC = np.empty((p, n))
    dD = np.empty(p)
    for i, d in enumerate(derivs):
        aug = StateSpace(
            np.block([[ss.A, np.zeros((n, n))], [d.A, ss.A]]),
            np.vstack([ss.B, d.B]),
            np.hstack([d.C, ss.C]),
            d.D,
        )
        da = discretize(aug, dt, hold)
        Psi[i] = da.Phi[n:, :n]
        dGamma[i] = da.Gamma[n:]
        dC[i] = da.C[:n]
        dD[i] = da.D
    g = np.empty(N)
    dg = np.empty((p, N))
    g[0], dg[:, 0] = base.D, dD
    if N > 1:
        s, ds = _krylov_sensitivity_columns(base.Phi, Psi, base.Gamma, dGamma, N - 1)
        g[1:] = base.C @ s
        dg[:, 1:] = np.einsum("pn,nk->pk", dC, s) + np.einsum("n,pnk->pk", base.C, ds)
    y_and_dy = causal_convolve(np.vstack([g, dg]), u)
    return y_and_dy[0], y_and_dy[1:].T


def _krylov_sensitivity_columns(Phi, Psi, v, dv, count):
    """Columns of [[Phi,0],[Psi_i,Phi]]^k [v; dv_i] for k < count, all i at once (doubling)."""
    s = v.reshape(-1, 1)
    ds = dv[:, :, None]
    P, Q = Phi, Psi
    while s.shape[1] < count:
        take = count - s.shape[1]
        s_head, ds_head = s[:, :take], ds[:, :, :take]
        new_ds = Q @ s_head + P @ ds_head
        s = np.hstack([s, P @ s_head])
        ds = np.concatenate([ds, new_ds], axis=2)
        if s.shape[1] < count:
            Q = Q @ P + P @ Q
            P = P @ P
    return s, ds
