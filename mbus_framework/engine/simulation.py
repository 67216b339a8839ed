"""Exact discrete-time simulation of a medium model and its exact parameter sensitivities.

Problem
-------
A medium model gives a continuous single-input single-output system (time t [s], input force
u [N], output force y [N])

    dz/dt = A z + B u,      y = C z + D u,        z(0) = 0.

The input is known only at the samples u[k] = u(k h), h = ``dt`` [s]. Between samples it is
reconstructed by a hold:

* ``"zoh"`` (zero-order hold): u(t) = u[k] on [k h, (k+1) h). This is what a function
  generator playing a sampled waveform does, and what the dissertation's RK4 (eq. 3.22)
  approximates when the input is held over the step.
* ``"foh"`` (first-order hold): u linear between samples, starting at u[0] at t = 0. This is
  python-control's ``forced_response`` convention.

The engine returns y[k] = y(k h) of the *continuous* system for that input, exactly (to
round-off): no time-stepping error whatever the step, stiffness or damping.

Discretisation
--------------
With Phi = e^{A h} and the phi-functions phi_1(z) = (e^z - 1)/z, phi_2(z) = (e^z - 1 - z)/z^2,

    Gamma0 = int_0^h e^{A s} ds B        = h phi_1(A h) B,
    Gamma1 = int_0^h e^{A s} (1 - s/h) ds B = h phi_2(A h) B,

    ZOH:  x[k+1] = Phi x[k] + Gamma0 u[k]
    FOH:  x[k+1] = Phi x[k] + (Gamma0 - Gamma1) u[k] + Gamma1 u[k+1].

For FOH the state xi[k] = x[k] - Gamma1 u[k] obeys xi[k+1] = Phi xi[k] + Gamma_eff u[k],
Gamma_eff = Gamma0 - Gamma1 + Phi Gamma1, y[k] = C xi[k] + (D + C Gamma1) u[k], and from rest
xi[0] = -Gamma1 u[0]. Hence, for both holds, the response from rest is the causal convolution

    y[k] = sum_{j<=k} g[k-j] u[j]  -  u[0] c[k],                                         (1)

    ZOH: g[0] = D,            g[m] = C Phi^(m-1) Gamma0 (m >= 1),  c = 0
    FOH: g[0] = D + C Gamma1, g[m] = C Phi^(m-1) Gamma_eff,         c[k] = C Phi^k Gamma1.

How (1) is evaluated: ``simulate`` on the modal path uses a block recursion over the modal
states (``_modal_block_response``: blocks of 32 samples, a Toeplitz product inside each
block, a prefix scan over block-start states; O(N) and no FFT). Sensitivities and the
doubling path convolve the kernels by FFT (O(N log N); the input spectrum is cached, so
refitting the same record costs one forward and one inverse transform per output).

Two ways to get the kernels g, c
--------------------------------
*Modal* (default when safe). A is balanced (T^-1 A T, T diagonal powers of two) and
diagonalised, A = V diag(lambda) V^-1. With c~ = C V, b~ = V^-1 B, residues r_i = c~_i b~_i
and z_i = lambda_i h, every kernel is a sum of modes

    g[m] = Re sum_i w_i r_i K(z_i) e^{z_i (m-1)},   c[k] = Re sum_i w_i r_i h phi_2(z_i) e^{z_i k}

with K = h phi_1(z) (ZOH) or h (phi_1 - phi_2 + e^z phi_2)(z) (FOH); w_i = 2 for one member of
each complex-conjugate pair, 1 for real eigenvalues (the partner is dropped). The power
table e^{z_i j} is built blockwise (exp of z_i r and of z_i b K, one matrix product), so the
kernels cost O(n N) without forming Phi^k.

*Repeated doubling* (safe fallback). Phi, Gamma0, Gamma1 from one matrix exponential of an
augmented matrix (Van Loan); the Krylov sequence [v, Phi v, Phi^2 v, ...] by doubling,
[S, Phi^(2^j) S]. It needs no eigendecomposition and is exact for defective
(repeated-eigenvalue, Jordan-block) models. Only the states a later doubling level reads are
formed (a third to a half of them); the kernel values beyond are projections
(C Phi^f) (Phi^k v). Cost O(n^2 N).

Choosing the path (``method="auto"``): the modal path is tried when the eigenvector matrix
of the balanced A is well conditioned (kappa_1(V) <= ``MODAL_MAX_CONDITION``) and, for
sensitivities, no two eigenvalues (nearly) coincide (relative gap >=
``MODAL_MIN_SEPARATION``). Its result is kept only if the error estimate
kappa x amplification is at most ``MODAL_MAX_AMPLIFICATION``, where the round-off
amplification of the modal sums is sum_i max|term_i| ||u||_2 / max |output| (see
``_output_amplification``); that catches nearly defective models (large,
cancelling residues or partial fractions) and records that end before the wave arrives (an
output ~1e-20 of the modal terms). Otherwise the doubling path runs. Both paths stay far
below the 1e-9 target: the modal path's measured error is < 180 eps kappa amplification
(< ~2e-10 where accepted), the doubling path's ~1e-14 (tests/test_simulation.py, the
benchmark). Fits evaluate one record many times: when its last output took the doubling path,
the doubling y is computed first and the modal y only when the decision could go the other
way, and a Jacobian at a theta whose modal y was just rejected skips the modal kernels
(``_surely_rejected``: the same path and result, only the order differs).

Threading: the engine's matrices are small (tens of states). Products are arranged so that
no single BLAS call is large enough for a threaded BLAS to split it across cores, which on
a shared machine costs far more than it saves; LAPACK's ``geev`` and ``expm`` are left as
they are.

Sensitivities
-------------
dy/dtheta_p is the output of the forward-sensitivity system

    d/dt [z; z_p] = [[A, 0], [A_p, A]] [z; z_p] + [B; B_p] u,   y_p = C_p z + C z_p + D_p u

(A_p = dA/dtheta_p, ...), which is itself linear; its exact discretisation is the exact
derivative of the discretised model, so dy/dtheta is exact, not a finite difference.
A_p, B_p, C_p, D_p come from complex-step differentiation of the model's own
``state_space`` (exact to round-off, no model-specific code).

In modal coordinates (A~_p = V^-1 A_p V, q_ij = c~_i A~_p,ij b~_j) the continuous impulse
response of the sensitivity is

    h_p(t) = sum_i (r'_i + alpha_i) e^{lambda_i t} + q_ii t e^{lambda_i t},
    r'_i = (C_p V)_i b~_i + c~_i (V^-1 B_p)_i,
    alpha_i = sum_{j != i} (q_ij + q_ji) / (lambda_i - lambda_j)

(the divided differences (e^{lambda_i t} - e^{lambda_j t}) / (lambda_i - lambda_j) of the
Frechet derivative of e^{A t}, split into partial fractions). Integrating against the hold
kernel gives

    g_p[m] = Re sum_i w_i e^{z_i (m-1)} [(r'_i + alpha_i) K_i + q_ii (dK/dlambda)_i + (m-1) h q_ii K_i],

and likewise for c_p; dK/dlambda uses phi_1' = phi_1 - phi_2, phi_2' = phi_2 - 2 phi_3.
The doubling path instead discretises the 2n-state sensitivity system per parameter.

Units: ``dt`` in seconds, theta in the model's SI units, y in the model's output units,
dy/dtheta_p in output units per unit of theta_p.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal, Sequence

import numpy as np
from scipy import fft as sfft
from scipy.linalg import expm
from scipy.linalg.lapack import dgebal

from mbus_framework.interfaces.model import MediumModel, StateSpace

Hold = Literal["zoh", "foh"]
Method = Literal["auto", "modal", "doubling"]

#: Largest kappa_1(V) (eigenvectors of the balanced A) for which the modal path is used.
MODAL_MAX_CONDITION = 5.0e3
#: Smallest relative eigenvalue separation for which modal *sensitivities* are tried.
MODAL_MIN_SEPARATION = 1.0e-8
#: Largest error estimate kappa * amplification accepted from the modal path: kappa is the
#: eigenvector conditioning, amplification the round-off amplification of the modal sums in
#: the outputs (see ``_output_amplification``). Over random Kelvin-Voigt chains (n 1-40,
#: parameters x0.03-30, 2-25 MHz, records 60-20000 samples, ZOH and FOH, y and dy/dtheta)
#: the modal path's relative error stayed below 180 eps kappa amplification, so 5e3 keeps it
#: below ~2e-10 (observed: < 5e-12 where accepted); the doubling path, used otherwise, is
#: good to ~1e-14. Table 3.1 (n = 10, 6200 samples): kappa 23, estimate 27.
MODAL_MAX_AMPLIFICATION = 5.0e3


# ---------------------------------------------------------------------------------------
# Discretisation (Van Loan) and repeated doubling: the reference path
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DiscreteSystem:
    """x[k+1] = Phi x[k] + Gamma u[k],  y[k] = C x[k] + D u[k]  (effective form for FOH).

    For FOH, ``Gamma`` is Gamma_eff = Gamma0 - Gamma1 + Phi Gamma1, ``D`` is D + C Gamma1 and
    ``Gamma1`` = h phi_2(A h) B is kept: from rest the effective state starts at
    -Gamma1 u[0], which adds -u[0] C Phi^k Gamma1 to y[k] (eq. (1) of the module docstring).
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
    _check_hold(hold)
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
        g[1:] = _krylov_outputs(sys.Phi, sys.Gamma, sys.C, count - 1)
    return g


def _mm(a: np.ndarray, b: np.ndarray, rows: int = 128) -> np.ndarray:
    """a @ b for a tall ``a`` (..., M, K), as a stack of small products.

    A tall product with a small inner dimension is exactly the shape a threaded BLAS splits
    across cores; on a shared machine that costs far more than it saves (measured: 25x
    slower with 2 busy cores). Stacking slices of ``rows`` rows keeps every call small and
    single-threaded, whatever the BLAS configuration.
    """
    M = a.shape[-2]
    if M <= rows:
        return a @ b
    m1 = (M // rows) * rows
    lead = a.shape[:-2]
    out = np.empty(np.broadcast_shapes(lead, b.shape[:-2]) + (M, b.shape[-1]), dtype=np.result_type(a, b))
    head = a[..., :m1, :].reshape(lead + (m1 // rows, rows, a.shape[-1]))
    bb = b if b.ndim == 2 else b[..., None, :, :]
    out[..., :m1, :] = (head @ bb).reshape(out.shape[:-2] + (m1, b.shape[-1]))
    if m1 < M:
        out[..., m1:, :] = a[..., m1:, :] @ b
    return out


def _doubling_schedule(count: int) -> tuple[list[tuple[int, int]], int]:
    """Levels (filled, take) of repeated doubling up to ``count`` terms, and the number of
    leading terms any level reads (``need``): level (f, t) forms terms f..f+t-1 from terms
    0..t-1 and Phi^f."""
    levels, filled = [], 1
    while filled < count:
        take = min(filled, count - filled)
        levels.append((filled, take))
        filled += take
    return levels, max((t for _, t in levels), default=1)


def _krylov_outputs(Phi: np.ndarray, v: np.ndarray, c: np.ndarray, count: int) -> np.ndarray:
    """c Phi^k v for k < count (count,), by doubling.

    Only the states Phi^k v that a later level reads are formed (k < ``need``, between a third
    and a half of ``count``); their outputs are c (Phi^k v), and the terms of a level (f, t)
    beyond them are the projections c Phi^(f+k) v = (c Phi^f) (Phi^k v), n flops each.
    """
    out = np.empty(count)
    if count == 0:
        return out
    levels, need = _doubling_schedule(count)
    S = np.empty((need, v.shape[0]))  # row k = (Phi^k v)^T
    S[0] = v
    PT = Phi.T
    for i, (filled, take) in enumerate(levels):
        head = S[:take]
        full = min(max(need - filled, 0), take)
        if full:
            S[filled : filled + full] = _mm(head[:full], PT)
        if full < take:  # small calls, see _mm
            out[filled + full : filled + take] = _mm(head[full:], (c @ PT.T)[:, None])[:, 0]
        if i + 1 < len(levels):
            PT = _mm(PT, PT, rows=32)
    out[:need] = _mm(S, c[:, None])[:, 0]
    return out


def _krylov_sensitivity_outputs(Phi, Psi, v, dv, c, dc, count):
    """Outputs of the doubling sensitivity recursion: for k < count,

        o[k] = c Phi^k v,    o_i[k] = dc_i Phi^k v + c ((d Phi^k)_i v + Phi^k dv_i),

    returned as o (count,) and o_p (p, count), using [[P, 0], [Q, P]]^2 = [[P^2, 0], [QP + PQ, P^2]]
    (P = Phi^f, Q_i = (d Phi^f)_i at level f). As in :func:`_krylov_outputs`, only the states
    s_k = Phi^k v, ds_{i,k} that a later level reads are formed; the terms of a level beyond
    them are the projections

        o[f+k] = (c P) s_k,   o_i[f+k] = (dc_i P + c Q_i) s_k + (c P) ds_{i,k}.
    """
    n, p = v.shape[0], dv.shape[0]
    o = np.empty(count)
    op = np.empty((p, count))
    if count == 0:
        return o, op
    levels, need = _doubling_schedule(count)
    s = np.empty((need, n))
    ds = np.empty((p, need, n))
    s[0] = v
    ds[:, 0] = dv
    P, Q = Phi, Psi
    for i, (filled, take) in enumerate(levels):
        s_head, ds_head = s[:take], ds[:, :take]
        full = min(max(need - filled, 0), take)
        if full:
            ds[:, filled : filled + full] = _mm(s_head[:full], Q.transpose(0, 2, 1)) + _mm(ds_head[:, :full], P.T)
            s[filled : filled + full] = _mm(s_head[:full], P.T)
        if full < take:
            cP = c @ P  # (n,)
            row = dc @ P + np.einsum("m,pmn->pn", c, Q)  # (p, n): dc_i P + c Q_i
            # stacks of small products (see _mm): s_k [c P, dc_i P + c Q_i] and ds_{i,k} (c P)
            both = _mm(s_head[full:], np.concatenate([cP[:, None], row.T], axis=1))  # (take - full, 1 + p)
            o[filled + full : filled + take] = both[:, 0]
            op[:, filled + full : filled + take] = both[:, 1:].T + _mm(ds_head[:, full:], cP[:, None])[..., 0]
        if i + 1 < len(levels):
            Q = _mm(Q, P, rows=32) + _mm(P, Q, rows=32)
            P = _mm(P, P, rows=32)
    both = _mm(s, np.concatenate([c[:, None], dc.T], axis=1))  # (need, 1 + p)
    o[:need] = both[:, 0]
    op[:, :need] = both[:, 1:].T + _mm(ds, c[:, None])[..., 0]
    return o, op


# ---------------------------------------------------------------------------------------
# Convolution
# ---------------------------------------------------------------------------------------
def causal_convolve(g: np.ndarray, u: np.ndarray) -> np.ndarray:
    """y[k] = sum_{j<=k} g[k-j] u[j] for k < N; g may carry leading batch axes (FFT)."""
    N = u.shape[-1]
    if N == 0:
        return np.zeros(np.broadcast_shapes(np.shape(g)[:-1], np.shape(u)[:-1]) + (0,))
    nfft = sfft.next_fast_len(2 * N - 1, real=True)
    G = sfft.rfft(g, nfft, axis=-1)
    U = _input_spectrum(u, nfft) if u.ndim == 1 else sfft.rfft(u, nfft, axis=-1)
    return sfft.irfft(G * U, nfft, axis=-1)[..., :N]


_SPECTRUM_CACHE: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _input_spectrum(u: np.ndarray, nfft: int) -> np.ndarray:
    """rfft(u, nfft), reused while the same record (compared by value) is simulated again."""
    hit = _SPECTRUM_CACHE.get(nfft)
    if hit is not None and hit[0].shape == u.shape and np.array_equal(hit[0], u):
        return hit[1]
    U = sfft.rfft(u, nfft)
    if len(_SPECTRUM_CACHE) >= 4:
        _SPECTRUM_CACHE.clear()
    _SPECTRUM_CACHE[nfft] = (np.array(u, copy=True), U)
    return U


def _respond(g: np.ndarray, corr: np.ndarray | None, u: np.ndarray) -> np.ndarray:
    """Eq. (1): causal convolution with the kernels g (..., N) minus u[0] times corr."""
    y = causal_convolve(g, u)
    if corr is not None and u.shape[-1]:
        y -= u[0] * corr
    return y


# ---------------------------------------------------------------------------------------
# phi-functions and the modal path
# ---------------------------------------------------------------------------------------
_TAYLOR_RADIUS = 1.0
#: 1/(j+3)! for the Taylor series of phi_3 (|z| < 1: the 20th term is below 1e-22).
_PHI3_TAYLOR = 1.0 / np.array([float(np.prod(np.arange(1, j + 4))) for j in range(20)])


def _expm1_complex(z: np.ndarray) -> np.ndarray:
    """e^z - 1 for complex z without cancellation for small Re z: expm1(x) cos y - 2 sin^2(y/2)."""
    x, y = z.real, z.imag
    with np.errstate(over="ignore", invalid="ignore"):
        re = np.expm1(x) * np.cos(y) - 2.0 * np.sin(0.5 * y) ** 2
        im = np.exp(x) * np.sin(y)
    return re + 1j * im


def phi_functions(z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """phi_1, phi_2, phi_3 at complex z, phi_k(z) = sum_j z^j / (j+k)!, to a few ulp.

    |z| < 1: Taylor series of phi_3, then phi_2 = 1/2 + z phi_3, phi_1 = 1 + z phi_2 (no
    cancellation). |z| >= 1: phi_1 = (e^z - 1)/z, phi_2 = (phi_1 - 1)/z, phi_3 = (phi_2 - 1/2)/z.
    """
    z = np.asarray(z, dtype=complex)
    small = np.abs(z) < _TAYLOR_RADIUS
    zs = np.where(small, z, 0.0)
    acc = np.zeros_like(zs)
    for c in _PHI3_TAYLOR[::-1]:
        acc = acc * zs + c
    p3s = acc
    p2s = 0.5 + zs * p3s
    p1s = 1.0 + zs * p2s
    if small.all():
        return p1s, p2s, p3s
    zl = np.where(small, 1.0, z)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        p1 = _expm1_complex(zl) / zl
        p2 = (p1 - 1.0) / zl
        p3 = (p2 - 0.5) / zl
    return np.where(small, p1s, p1), np.where(small, p2s, p2), np.where(small, p3s, p3)


@dataclass(frozen=True)
class ModalForm:
    """Eigendecomposition of a balanced continuous SISO system.

    lam: eigenvalues lambda_i of A [1/s]; V, W = V^-1: eigenvectors of the balanced matrix
    T^-1 A T (``scale`` = diag T); cb = C T V, bb = W T^-1 B (modal output/input vectors);
    d = D; keep/weight: the modes summed (one per conjugate pair, weight 2; real, weight 1);
    kappa = ||V||_1 ||W||_1; paired: the conjugate pairing held.
    """

    lam: np.ndarray
    V: np.ndarray
    W: np.ndarray
    scale: np.ndarray
    cb: np.ndarray
    bb: np.ndarray
    d: float
    keep: np.ndarray
    weight: np.ndarray
    kappa: float
    paired: bool

    def separation(self, dt: float) -> float:
        """min over i != j of |lambda_i - lambda_j| / max(|lambda_i|, |lambda_j|, 1/dt)."""
        lam = self.lam
        if lam.size < 2:
            return np.inf
        gap = np.abs(lam[:, None] - lam[None, :])
        mag = np.maximum(np.maximum(np.abs(lam)[:, None], np.abs(lam)[None, :]), 1.0 / dt)
        ratio = gap / mag
        np.fill_diagonal(ratio, np.inf)
        return float(ratio.min())


_RECENT_FORMS: list = []  # (key, modal form) of the last few systems


def modal_form(ss: StateSpace) -> ModalForm | None:
    """Balanced eigendecomposition of ``ss`` (float), or None when it cannot be formed.

    The last few are kept (keyed by the matrices' values): a local fit simulates, and then
    differentiates, the same system."""
    arrays = [np.ascontiguousarray(m) for m in ss]
    key = b"".join(m.tobytes() + f"{m.dtype}{m.shape}".encode() for m in arrays)
    for k, mf in _RECENT_FORMS:
        if k == key:
            return mf
    mf = _modal_form(ss)
    _RECENT_FORMS.insert(0, (key, mf))
    del _RECENT_FORMS[4:]
    return mf


def _modal_form(ss: StateSpace) -> ModalForm | None:
    A, B, C, D = ss
    n = A.shape[0]
    if n == 0 or not np.all(np.isfinite(A)):
        return None
    try:
        # diagonal balancing only (LAPACK gebal, no permutation): Ab = T^-1 A T, T = diag(scale)
        Ab, _, _, scale, info = dgebal(A, scale=1, permute=0)
        if info != 0:
            return None
        lam, V = np.linalg.eig(Ab)
        W = np.linalg.inv(V)
    except (np.linalg.LinAlgError, ValueError):
        return None
    if not np.isfinite(W).all():
        return None
    lam = np.asarray(lam, dtype=complex)
    V = np.asarray(V, dtype=complex)
    kappa = float(np.abs(V).sum(axis=0).max() * np.abs(W).sum(axis=0).max())
    # einsum, not BLAS: a threaded gemv on a busy machine costs milliseconds here
    cb = np.einsum("i,ij->j", C[0] * scale, V)
    bb = np.einsum("ij,j->i", W, B[:, 0] / scale)
    pos, neg = lam.imag > 0, lam.imag < 0
    paired = bool(pos.sum() == neg.sum())
    if paired:
        keep = np.nonzero(~neg)[0]
        weight = np.where(pos[keep], 2.0, 1.0)
    else:  # not expected from LAPACK on a real matrix; sum every mode
        keep = np.arange(n)
        weight = np.ones(n)
    return ModalForm(lam, V, W, scale, cb, bb, float(D[0, 0]), keep, weight, kappa, paired)


def _modal_ok(mf: ModalForm | None, dt: float, sensitivities: bool) -> bool:
    if mf is None or not mf.paired or mf.kappa > MODAL_MAX_CONDITION:
        return False
    if np.any(mf.lam.real * dt > 700.0):  # e^{lambda h} would overflow the power table
        return False
    return not sensitivities or mf.separation(dt) >= MODAL_MIN_SEPARATION


def _hold_weights(z: np.ndarray, dt: float, hold: Hold, derivatives: bool = True):
    """K, dK/dlambda (main kernel) and L, dL/dlambda (FOH start correction) per mode.

    ZOH: K = h phi_1(z). FOH: K = h (phi_1 - phi_2 + e^z phi_2)(z), L = h phi_2(z), z = lambda h.
    ``derivatives=False`` (ZOH only) skips dK and uses phi_1 = expm1(z)/z, which is accurate
    to a few ulp (normwise) for every z, so no series is needed.
    """
    h = dt
    if hold == "zoh" and not derivatives:
        nz = z != 0
        with np.errstate(over="ignore", invalid="ignore"):
            p1 = np.where(nz, _expm1_complex(z) / np.where(nz, z, 1.0), 1.0)
        return h * p1, None, None, None
    p1, p2, p3 = phi_functions(z)
    if hold == "zoh":
        return h * p1, h * h * (p1 - p2), None, None
    ez = np.exp(z)
    K = h * (p1 - p2 + ez * p2)
    dK = h * h * (p1 - 2.0 * p2 + 2.0 * p3 + 2.0 * ez * (p2 - p3))
    return K, dK, h * p2, h * h * (p2 - 2.0 * p3)


def _mode_sums(z: np.ndarray, coef: np.ndarray, count: int) -> np.ndarray:
    """Re sum_i coef[r, i] e^{z_i j} for j = 0..count-1, rows r (R, count) real.

    Block evaluation: j = b K + s; e^{z j} = e^{z b K} e^{z s}; one real matrix product
    [Re, -Im](coef e^{z b K}) @ [Re; Im](e^{z s}) of cost 2 R n count.
    """
    R, n = coef.shape
    if count == 0:
        return np.zeros((R, 0))
    K = int(min(max(16, np.sqrt(count)), 1024, count))
    nb = -(-count // K)
    small = np.exp(np.outer(z, np.arange(K)))  # (n, K)
    big = np.exp(np.outer(np.arange(nb) * float(K), z))  # (nb, n)
    cb = coef[:, None, :] * big[None, :, :]  # (R, nb, n)
    left = np.concatenate([cb.real, -cb.imag], axis=2)  # (R, nb, 2n)
    right = np.concatenate([small.real, small.imag], axis=0)  # (2n, K)
    # R stacks of small products (single-threaded BLAS calls, see _mm); (R, nb, K) is
    # already the row-major layout of (R, nb K)
    return _mm(left, right).reshape(R, nb * K)[:, :count]


def _modal_kernels(mf: ModalForm, dt: float, hold: Hold, N: int, derivs=None):
    """Kernels g (1+p, N) and, for FOH, c (1+p, N) of eq. (1) by the modal formulas, with
    the bounds sum_i max_j |term_i(j)| of their modal sums per row (see ``_term_bounds``)."""
    lam = mf.lam
    z = lam * dt
    K, dK, L, dL = _hold_weights(z, dt, hold, derivs is not None)
    k = mf.keep
    w = mf.weight
    r = mf.cb * mf.bb  # residues, all modes
    rows0 = [w * r[k] * K[k]]  # (1 + j) coefficients in eq. (1) kernels, see _mode_sums
    rows1 = [np.zeros_like(rows0[0])]
    if hold == "foh":
        rows0.append(w * r[k] * L[k])
        rows1.append(rows1[0])
    p = 0
    dD = None
    if derivs is not None:
        p = len(derivs)
        s = mf.scale
        Ap = np.stack([np.asarray(d.A, float) for d in derivs]) * (s[None, None, :] / s[None, :, None])
        At = _mm(_mm(mf.W, Ap, rows=32), mf.V, rows=32)  # (p, n, n) modal A_p
        bp = np.einsum("pj,ij->pi", np.stack([np.asarray(d.B, float)[:, 0] for d in derivs]) / s, mf.W)
        cp = np.einsum("pi,ij->pj", np.stack([np.asarray(d.C, float)[0] for d in derivs]) * s, mf.V)
        dD = np.array([float(np.asarray(d.D, float).reshape(-1)[0]) for d in derivs])
        Q = mf.cb[None, :, None] * At * mf.bb[None, None, :]  # q_ij
        S = Q + Q.transpose(0, 2, 1)
        diff = lam[:, None] - lam[None, :]
        np.fill_diagonal(diff, 1.0)
        Rinv = 1.0 / diff
        np.fill_diagonal(Rinv, 0.0)
        alpha = (S * Rinv[None]).sum(axis=2)  # (p, n)
        qd = np.diagonal(Q, axis1=1, axis2=2)  # (p, n)
        rp = cp * mf.bb[None, :] + mf.cb[None, :] * bp + alpha
        rp, qd = rp[:, k], qd[:, k]
        rows0.append(w * (rp * K[k] + qd * dK[k]))
        rows1.append(w * (qd * dt * K[k]))
        if hold == "foh":
            rows0.append(w * (rp * L[k] + qd * dL[k]))
            rows1.append(w * (qd * dt * L[k]))
    coef0 = np.vstack([np.atleast_2d(x) for x in rows0])
    coef1 = np.vstack([np.atleast_2d(x) for x in rows1])
    if p:
        nrow = coef0.shape[0]
        both = _mode_sums(z[k], np.vstack([coef0, coef1]), N)
        vals = both[:nrow] + np.arange(N) * both[nrow:]
    else:
        vals = _mode_sums(z[k], coef0, N)
    bounds = _term_bounds(z[k], coef0, coef1, N)
    # Row layout: [g, (c)] then [g_p (p rows), (c_p (p rows))].
    nbase = 2 if hold == "foh" else 1
    base = vals[:nbase]
    sens = vals[nbase:].reshape(nbase, p, N) if p else None
    gb = np.concatenate([bounds[:1], bounds[nbase : nbase + p]])
    cb = None
    if hold == "foh":  # c enters twice: in g[0] (times every u[k]) and in the start term
        cb = np.concatenate([bounds[1:2], bounds[nbase + p :]])
        gb = gb + cb
    g = np.empty((1 + p, N))
    g[0, 1:] = base[0, : N - 1]
    if p:
        g[1:, 1:] = sens[0][:, : N - 1]
    if N:
        g[0, 0] = mf.d
        if p:
            g[1:, 0] = dD
    corr = None
    if hold == "foh":
        corr = np.empty((1 + p, N))
        corr[0] = base[1]
        if p:
            corr[1:] = sens[1]
        if N:
            g[:, 0] += corr[:, 0]
    return g, corr, gb, cb


def _term_bounds(z: np.ndarray, coef0: np.ndarray, coef1: np.ndarray, N: int) -> np.ndarray:
    """Per row r: sum_i max_{j<N} |coef0_ri + j coef1_ri| |e^{z_i j}| (bounded termwise).

    Each mode's term is computed with a relative error of a few eps, so eps times this
    bounds the absolute round-off of a modal sum Re sum_i (coef0_i + j coef1_i) e^{z_i j}.
    """
    if N == 0:
        return np.zeros(coef0.shape[0])
    a = -z.real  # decay per sample
    j_last = float(N - 1)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        m0 = np.where(a >= 0, 1.0, np.exp(-a * j_last))
        jstar = np.where(a > 0, 1.0 / np.where(a > 0, a, 1.0), np.inf)
        m1 = np.where(jstar < j_last, jstar * np.exp(-1.0), j_last * np.exp(-a * j_last))
        return np.abs(coef0) @ m0 + np.abs(coef1) @ m1


def _output_amplification(out: np.ndarray, gbound: np.ndarray, cbound, u: np.ndarray) -> float:
    """Round-off amplification of outputs computed from modal sums, worst row.

    A kernel whose modal sum has termwise bound B carries an absolute error ~eps B at every
    lag; convolved with u these errors add up like a random walk, ~eps B ||u||_2 (and the FOH
    start term adds eps B_c |u[0]|). Divided by the output's peak this is the factor by which
    round-off is amplified: large when the modes nearly cancel (nearly defective A) or when
    the output is much smaller than its modal parts (a record that ends before the wave
    arrives). Returns inf for non-finite outputs.
    """
    out = np.atleast_2d(out)
    bound = np.atleast_1d(gbound) * np.sqrt(float(np.dot(u, u)))
    if cbound is not None and u.size:
        bound = bound + np.atleast_1d(cbound) * abs(float(u[0]))
    peak = np.abs(out).max(axis=1, initial=0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(bound == 0.0, 0.0, bound / peak)
    amp = float(ratio.max(initial=0.0))
    return amp if np.isfinite(amp) and np.all(np.isfinite(peak)) else np.inf


_BLOCK = 32  # block length of the modal block recursion (samples)


@lru_cache(maxsize=8)
def _toeplitz_index(L: int) -> tuple[np.ndarray, np.ndarray]:
    """Index r - r' (clipped at 0) and mask r >= r' of an upper-triangular L x L Toeplitz matrix."""
    d = np.arange(L)[None, :] - np.arange(L)[:, None]
    return np.maximum(d, 0), d >= 0


def _modal_block_response(mf: ModalForm, dt: float, hold: Hold, u: np.ndarray) -> tuple[np.ndarray, float]:
    """Output y (N,) of eq. (1) by a block recursion over the modal states, and the
    round-off amplification of its modal sums.

    With zeta_i[k] = sum_{j<k} mu_i^(k-1-j) u[j] (mu_i = e^{z_i}) and a_i = w_i r_i K_i,

        y[k] = g[0] u[k] + Re sum_i a_i zeta_i[k] - u[0] c[k].

    Records are cut into blocks of L samples (U, nb x L). Inside a block the response to the
    block's own samples is a product with the L x L Toeplitz matrix of g[0..L-1]; the
    earlier blocks act through the block-start states zeta[bL], which obey
    zeta[(b+1)L] = mu^L zeta[bL] + sum_r mu^(L-1-r) u[bL+r] (a first-order recursion over
    blocks, evaluated as a doubling prefix scan). Cost O(N (L + 4 n)) with no FFT: linear in
    N. The FOH start term -u[0] c[k] = Re sum_i e_i mu_i^k enters through the same block-start
    product (e_i mu_i^(bL)).

    Returns y and its round-off amplification (:func:`_output_amplification`).
    """
    N = u.shape[-1]
    k, w = mf.keep, mf.weight
    z = mf.lam[k] * dt
    K, _, Lh, _ = _hold_weights(mf.lam * dt, dt, hold, derivatives=False)
    r = w * (mf.cb * mf.bb)[k]
    a = r * K[k]
    d0 = mf.d
    if hold == "foh":
        c0 = r * Lh[k]  # c[k] = Re sum c0_i mu_i^k
        d0 = d0 + float(np.sum(c0).real)
    if N == 0:
        return np.zeros(0), 0.0
    L = min(_BLOCK, N)
    nb = -(-N // L)
    n = z.size
    small = np.exp(z[:, None] * np.arange(L + 1))  # mu^r, r = 0..L   (n, L+1)
    # kernel over the first block, and Toeplitz matrix T[r', r] = g[r - r'] (r >= r')
    gL = np.empty(L)
    gL[0] = d0
    gL[1:] = (a @ small[:, : L - 1]).real
    idx, mask = _toeplitz_index(L)
    T = np.where(mask, gL[idx], 0.0)
    U = np.zeros(nb * L)
    U[:N] = u
    U = U.reshape(nb, L)
    Y = _mm(U, T)
    if nb > 1 or hold == "foh":
        srev = small[:, L - 1 :: -1]  # mu^(L-1-r), r = 0..L-1   (n, L)
        S2 = _mm(U, np.concatenate([srev.real, srev.imag], axis=0).T)  # (nb, 2n)
        X = S2[:, :n] + 1j * S2[:, n:]
        P, d = small[:, L].copy(), 1
        while d < nb:  # inclusive scan X[b] = sum_{b'<=b} mu^(L(b-b')) S[b']
            X[d:] += P * X[:-d]
            P *= P
            d *= 2
        M = np.zeros((nb, n), dtype=complex)
        M[1:] = X[:-1] * a  # zeta[bL] = X[b-1]
        if hold == "foh":
            big = np.exp(z[None, :] * (np.arange(nb) * float(L))[:, None])  # mu^(bL)   (nb, n)
            M -= (u[0] * c0) * big
        Y += _mm(np.concatenate([M.real, M.imag], axis=1), np.concatenate([small[:, :L].real, -small[:, :L].imag], axis=0))
    y = Y.reshape(-1)[:N]
    grow = np.where(z.real > 0, np.exp(z.real * (N - 1)), 1.0)  # max_j |mu^j|
    gbound = float(np.abs(a) @ grow)
    cbound = None
    if hold == "foh":  # c enters twice: in g[0] (times every u[k]) and in the start term
        cbound = float(np.abs(c0) @ grow)
        gbound += cbound
    return y, _output_amplification(y, gbound, cbound, u)


_REJECTED: list = []  # (modal form, dt, hold, u, amplification) of recent rejected outputs y
_LAST_Y_PATH: list = []  # [(dt, hold, u, path)] of the last output y computed by method 'auto'


def _surely_rejected(amp: float, kappa: float, u: np.ndarray) -> bool:
    """True when a modal output whose amplification, measured on *another* computation of the
    same y (block recursion, FFT convolution or the doubling path), is ``amp`` would be
    rejected however the round-off falls.

    Two computations of y differ by at most ~c eps kappa B ||u||_1 (B the termwise bound,
    c = 1e3 generous), so the modal amplification B ||u||_2 / peak is at least
    1 / (1/amp + c eps kappa ||u||_1 / ||u||_2) >= 1 / (1/amp + c eps kappa sqrt(N)); the
    decision is taken only when that exceeds the threshold by 1e-6."""
    if not np.isfinite(amp) or amp <= 0.0:
        return False
    slack = 1e3 * np.finfo(float).eps * kappa * np.sqrt(max(u.shape[-1], 1))
    return kappa / (1.0 / amp + slack) > MODAL_MAX_AMPLIFICATION * (1.0 + 1e-6)


def _note_rejection(mf: ModalForm, dt: float, hold: Hold, u: np.ndarray, amp: float) -> None:
    """Remember that the modal output y of this system was rejected (amplification ``amp``)."""
    if np.isfinite(amp):
        _REJECTED.insert(0, (mf, dt, hold, np.array(u, copy=True), amp))
        del _REJECTED[4:]


def _rejected_before(mf: ModalForm, dt: float, hold: Hold, u: np.ndarray) -> bool:
    """True when the modal y of the same system, step, hold and input was rejected by a margin
    (:func:`_surely_rejected`).

    The sensitivity path's amplification is a maximum over rows whose first row is y itself,
    with the same termwise bound B (to a few ulp), so it would reject too: the modal kernels
    are skipped (the doubling path runs, as it would). A local fit evaluates y and then
    dy/dtheta at the same theta, so this saves one modal attempt per Jacobian on records
    where the modal path is not accepted.
    """
    for mf0, dt0, hold0, u0, amp in _REJECTED:
        if mf0 is mf and dt0 == dt and hold0 == hold and u0.shape == u.shape and np.array_equal(u0, u):
            return _surely_rejected(amp, mf.kappa, u)
    return False


def _expect_doubling(dt: float, hold: Hold, u: np.ndarray) -> bool:
    """True when the last output y computed for this record (step, hold, input) took the doubling path."""
    if not _LAST_Y_PATH:
        return False
    dt0, hold0, u0, path = _LAST_Y_PATH[0]
    return path == "doubling" and dt0 == dt and hold0 == hold and u0.shape == u.shape and np.array_equal(u0, u)


def _note_path(dt: float, hold: Hold, u: np.ndarray, path: str) -> None:
    if _LAST_Y_PATH and _LAST_Y_PATH[0][0] == dt and _LAST_Y_PATH[0][1] == hold and np.array_equal(_LAST_Y_PATH[0][2], u):
        _LAST_Y_PATH[0] = (dt, hold, _LAST_Y_PATH[0][2], path)
    else:
        _LAST_Y_PATH[:] = [(dt, hold, np.array(u, copy=True), path)]


def _modal_y_bounds(mf: ModalForm, dt: float, hold: Hold, N: int) -> tuple[float, float | None]:
    """Termwise bounds (g, c) of the modal sums of y, as :func:`_modal_block_response` forms them."""
    k, w = mf.keep, mf.weight
    z = mf.lam[k] * dt
    K, _, Lh, _ = _hold_weights(mf.lam * dt, dt, hold, derivatives=False)
    r = w * (mf.cb * mf.bb)[k]
    grow = np.where(z.real > 0, np.exp(z.real * (N - 1)), 1.0)
    gbound = float(np.abs(r * K[k]) @ grow)
    cbound = None
    if hold == "foh":
        cbound = float(np.abs(r * Lh[k]) @ grow)
        gbound += cbound
    return gbound, cbound


def _doubling_y(ss: StateSpace, u: np.ndarray, dt: float, hold: Hold) -> np.ndarray:
    g, corr = _doubling_kernels(ss, dt, hold, u.shape[-1])
    return _respond(g[0], None if corr is None else corr[0], u)


def _simulate_y(ss: StateSpace, u: np.ndarray, dt: float, hold: Hold, method: Method) -> tuple[np.ndarray, str]:
    """Output y of eq. (1) and the path used (modal block recursion, or doubling + FFT).

    With ``method='auto'``, when the last y of the same record took the doubling path, the
    doubling y is computed first; if its amplification shows the modal y would surely be
    rejected (:func:`_surely_rejected`), it is returned without forming the modal y. Otherwise
    the modal y decides as usual. The result is the same either way; only the order differs.
    """
    _check_method(hold, method)
    if method != "doubling":
        mf = modal_form(ss)
        if method == "modal" and mf is None:
            raise ValueError("the modal path needs a diagonalisable A with finite eigenvectors")
        if method == "modal" or _modal_ok(mf, dt, False):
            yd = None
            if method == "auto" and u.shape[-1] and _expect_doubling(dt, hold, u):
                yd = _doubling_y(ss, u, dt, hold)
                with np.errstate(over="ignore", invalid="ignore", under="ignore", divide="ignore"):
                    amp_d = _output_amplification(yd, *_modal_y_bounds(mf, dt, hold, u.shape[-1]), u)
                if _surely_rejected(amp_d, mf.kappa, u):
                    _note_rejection(mf, dt, hold, u, amp_d)
                    return yd, "doubling"
            with np.errstate(over="ignore", invalid="ignore", under="ignore", divide="ignore"):
                y, amp = _modal_block_response(mf, dt, hold, u)
            if method == "modal" or amp * mf.kappa <= MODAL_MAX_AMPLIFICATION:
                if method == "auto":
                    _note_path(dt, hold, u, "modal")
                return y, "modal"
            _note_rejection(mf, dt, hold, u, amp)
            _note_path(dt, hold, u, "doubling")
            if yd is not None:
                return yd, "doubling"
    return _doubling_y(ss, u, dt, hold), "doubling"


def _doubling_kernels(ss: StateSpace, dt: float, hold: Hold, N: int, derivs=None):
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
            corr[0] = _krylov_outputs(base.Phi, base.Gamma1, base.C, N)
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
        g[0, 1:], g[1:, 1:] = _krylov_sensitivity_outputs(base.Phi, Psi, base.Gamma, dGamma, base.C, dC, N - 1)
    if corr is not None:
        corr[0], corr[1:] = _krylov_sensitivity_outputs(base.Phi, Psi, base.Gamma1, dGamma1, base.C, dC, N)
    return g, corr


def _check_method(hold, method) -> None:
    _check_hold(hold)
    if method not in ("auto", "modal", "doubling"):
        raise ValueError(f"method must be 'auto', 'modal' or 'doubling', not {method!r}")


def _simulate_sens(ss: StateSpace, derivs, u: np.ndarray, dt: float, hold: Hold, method: Method):
    """[y; dy/dtheta_1; ...] (1+p, N) of eq. (1) and the path used ('modal' or 'doubling')."""
    _check_method(hold, method)
    N = u.shape[-1]
    if method != "doubling":
        mf = modal_form(ss)
        if method == "modal" and mf is None:
            raise ValueError("the modal path needs a diagonalisable A with finite eigenvectors")
        if method == "modal" or (_modal_ok(mf, dt, True) and not _rejected_before(mf, dt, hold, u)):
            with np.errstate(over="ignore", invalid="ignore", under="ignore", divide="ignore"):
                g, corr, gb, cb = _modal_kernels(mf, dt, hold, N, derivs)
                out = _respond(g, corr, u)
                amp = _output_amplification(out, gb, cb, u)
            if method == "modal" or amp * mf.kappa <= MODAL_MAX_AMPLIFICATION:
                return out, "modal"
    g, corr = _doubling_kernels(ss, dt, hold, N, derivs)
    return _respond(g, corr, u), "doubling"


def engine_path(
    ss: StateSpace,
    dt: float,
    sensitivities: bool = False,
    u: np.ndarray | None = None,
    hold: Hold = "zoh",
    derivatives: Sequence[StateSpace] | None = None,
) -> str:
    """Which path ``method='auto'`` takes: 'modal' or 'doubling'.

    Without ``u`` only the a-priori checks (conditioning, eigenvalue separation) are
    applied. With the input record ``u`` the outputs are computed and the error estimate
    decides too, as in a real call; sensitivities then need ``derivatives`` (from
    :func:`state_space_derivatives`).
    """
    ss = as_float_ss(ss)
    if u is None:
        return "modal" if _modal_ok(modal_form(ss), dt, sensitivities) else "doubling"
    u = np.asarray(u, dtype=float)
    if not sensitivities:
        return _simulate_y(ss, u, float(dt), hold, "auto")[1]
    if derivatives is None:
        raise ValueError("pass derivatives=state_space_derivatives(model, theta) with u")
    return _simulate_sens(ss, derivatives, u, float(dt), hold, "auto")[1]


def _check_hold(hold) -> None:
    if hold not in ("zoh", "foh"):
        raise ValueError(f"hold must be 'zoh' or 'foh', not {hold!r}")


# ---------------------------------------------------------------------------------------
# Public entry points
# ---------------------------------------------------------------------------------------
def simulate_ss(
    ss: StateSpace, u: np.ndarray, dt: float, hold: Hold = "zoh", *, method: Method = "auto"
) -> np.ndarray:
    """Output y (N,) from rest of a continuous SISO system for samples ``u`` at ``dt`` [s]."""
    u = np.asarray(u, dtype=float)
    return _simulate_y(as_float_ss(ss), u, float(dt), hold, method)[0]


def simulate(
    model: MediumModel, theta, u: np.ndarray, dt: float, hold: Hold = "zoh", *, method: Method = "auto"
) -> np.ndarray:
    """Model output y [N] (shape (N,)) for input force u [N] sampled at ``dt`` [s], from rest."""
    if not getattr(model, "has_state_space", True):
        from mbus_framework.engine.convolution import simulate_response

        _check_hold(hold)
        return simulate_response(model, theta, u, dt, hold)
    return simulate_ss(model.state_space(np.asarray(theta, dtype=float)), u, dt, hold, method=method)


def simulate_batch(
    model: MediumModel,
    thetas,
    u: np.ndarray,
    dt: float,
    hold: Hold = "zoh",
    *,
    method: Method = "auto",
) -> np.ndarray:
    """Outputs (B, N) for a batch of parameter vectors ``thetas`` (B, p) and one input u (N,)."""
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    u = np.asarray(u, dtype=float)
    if not getattr(model, "has_state_space", True):
        return np.array([simulate(model, th, u, dt, hold) for th in thetas]).reshape(len(thetas), u.shape[-1])
    out = np.empty((thetas.shape[0], u.shape[-1]))
    for b, th in enumerate(thetas):
        out[b] = _simulate_y(as_float_ss(model.state_space(th)), u, float(dt), hold, method)[0]
    return out


def state_space_derivatives(model: MediumModel, theta) -> list[StateSpace]:
    """dA/dtheta_i, dB/dtheta_i, dC/dtheta_i, dD/dtheta_i by complex step (exact to round-off).

    M'(theta) = Im M(theta + i s e_i) / s with s = 1e-20 |theta_i| (1e-20 when theta_i = 0):
    no subtraction, so no cancellation; the truncation error O(s^2) is far below round-off.
    Requires the model to be written with analytic arithmetic (see :mod:`mbus_framework.engine.arrays`).
    """
    theta = np.asarray(theta, dtype=float)
    out = []
    for i in range(theta.size):
        step = 1e-20 * (abs(theta[i]) if theta[i] != 0.0 else 1.0)
        tc = theta.astype(complex)
        tc[i] += 1j * step
        ss = model.state_space(tc)
        out.append(StateSpace(*(np.atleast_2d(np.imag(np.asarray(m, dtype=complex))) / step for m in ss)))
    return out


def simulate_with_sensitivities(
    model: MediumModel, theta, u: np.ndarray, dt: float, hold: Hold = "zoh", *, method: Method = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """Output y (N,) and exact sensitivities dy/dtheta (N, p) of the sampled model output."""
    theta = np.asarray(theta, dtype=float)
    u = np.asarray(u, dtype=float)
    if not getattr(model, "has_state_space", True):
        from mbus_framework.engine.convolution import simulate_response_with_sensitivities

        _check_hold(hold)
        return simulate_response_with_sensitivities(model, theta, u, dt, hold)
    ss = as_float_ss(model.state_space(theta))
    derivs = state_space_derivatives(model, theta)
    out, _ = _simulate_sens(ss, derivs, u, float(dt), hold, method)
    return out[0], np.ascontiguousarray(out[1:].T)


def simulate_with_sensitivities_batch(
    model: MediumModel,
    thetas,
    u: np.ndarray,
    dt: float,
    hold: Hold = "zoh",
    *,
    method: Method = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """Outputs (B, N) and sensitivities (B, N, p) for parameter vectors ``thetas`` (B, p)."""
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    u = np.asarray(u, dtype=float)
    N, nb, p = u.shape[-1], thetas.shape[0], thetas.shape[1]
    if not getattr(model, "has_state_space", True):
        pairs = [simulate_with_sensitivities(model, th, u, dt, hold) for th in thetas]
        return np.array([y for y, _ in pairs]).reshape(nb, N), np.array([J for _, J in pairs]).reshape(nb, N, p)
    out = np.empty((nb, 1 + p, N))
    for b, th in enumerate(thetas):
        ss = as_float_ss(model.state_space(th))
        out[b] = _simulate_sens(ss, state_space_derivatives(model, th), u, float(dt), hold, method)[0]
    return out[:, 0], np.ascontiguousarray(out[:, 1:].transpose(0, 2, 1))


__all__: Sequence[str] = (
    "DiscreteSystem",
    "Hold",
    "Method",
    "ModalForm",
    "as_float_ss",
    "causal_convolve",
    "discretize",
    "engine_path",
    "markov_parameters",
    "modal_form",
    "phi_functions",
    "simulate",
    "simulate_batch",
    "simulate_ss",
    "simulate_with_sensitivities",
    "simulate_with_sensitivities_batch",
    "state_space_derivatives",
)
