"""Frequency responses of a medium model, with exact parameter derivatives.

Two responses of the continuous SISO model dz/dt = A z + B u, y = C z + D u:

* continuous   G(s) = C (sI - A)^-1 B + D,  s = i 2 pi f;
* ZOH-sampled  H(z) = C (zI - e^{Ah})^-1 Gamma0 + D,  Gamma0 = h phi_1(Ah) B,  z = e^{i 2 pi f h}:
  the exact ratio Y_k / U_k of the lines of a periodic steady state sampled every h seconds
  with the input held between samples (what :mod:`mbus_framework.engine.simulation` simulates).

Both are C f(A) B + D for a scalar function of an eigenvalue,

    continuous  f(lam) = 1 / (s - lam),        zoh  f(lam) = h phi_1(lam h) / (z - e^{lam h}),

so with the balanced eigendecomposition A = T V diag(lam) W T^-1 (``simulation.modal_form``)
H = cb diag(f(lam)) bb + D, and by the Daleckii-Krein formula the derivative along dA, dB, dC is

    dH = (dC T V) diag(f) bb + cb diag(f) (W T^-1 dB) + cb (F o (W T^-1 dA T V)) bb + dD,
    F_ij = (f(lam_i) - f(lam_j)) / (lam_i - lam_j),   F_ii = f'(lam_i).

dA, dB, dC, dD come from complex-step differentiation of the model's ``state_space``. When
the eigenvectors are ill conditioned (nearly defective models), response and Jacobian come
from a direct solve per frequency with the adjoint; so do the lines where the modal sum's error
bound exceeds ``PEAK_TOLERANCE`` of the response's peak (:func:`_cancelling`):
x = (sI - A)^-1 B, w^T = C (sI - A)^-1,

    dH = dC x + w^T dA x + w^T dB + dD,

sampled with Phi, Gamma0 for A, B and s = z, their derivatives being the Frechet derivative of
the Van Loan exponential expm([[A h, B h], [0, 0]]) along [[dA h, dB h], [0, 0]].
"""
from __future__ import annotations

import numpy as np

from mbus_framework.engine.simulation import (
    MODAL_MAX_CONDITION,
    ModalForm,
    as_float_ss,
    modal_form,
    state_space_derivatives,
)
from mbus_framework.interfaces.model import MediumModel, StateSpace
from mbus_framework.engine.hold import hold_response

#: Relative eigenvalue gap below which a divided difference is replaced by the derivative.
_CLOSE = 1e-7
#: Error of a modal-sum line, relative to the response's peak, above which it is solved directly.
PEAK_TOLERANCE = 1e-9


_RECENT: list = []  # (model, theta bytes, ss, modal form) of the last few parameter vectors


def _system(model: MediumModel, theta: np.ndarray):
    """(float state space, modal form or None) at ``theta``; the last few are kept, since a
    local fit evaluates the response, its Jacobian and the record's tail at the same point."""
    key = theta.tobytes()
    for entry in _RECENT:
        if entry[0] is model and entry[1] == key:
            return entry[2], entry[3]
    ss = as_float_ss(model.state_space(theta))
    mf = modal_form(ss)
    _RECENT.insert(0, (model, key, ss, mf))
    del _RECENT[4:]
    return ss, mf


def modal_response(mf: ModalForm, s: np.ndarray) -> np.ndarray:
    """Continuous G(s) = D + sum_i r_i / (s - lam_i) from a modal form, any complex s."""
    r = mf.cb * mf.bb
    return mf.d + (r[None, :] / (np.asarray(s)[:, None] - mf.lam[None, :])).sum(axis=1)


def _point_values(lam: np.ndarray, f: np.ndarray, dt: float | None):
    """f(lam) and f'(lam) per (frequency, mode), shape (F, n)."""
    if dt is None:
        d = 2j * np.pi * f[:, None] - lam[None, :]
        return 1.0 / d, 1.0 / d**2
    x = lam * dt
    E = np.exp(x)
    small = np.abs(x) <= 1e-8
    safe = np.where(small, 1.0, lam)
    K = np.where(small, dt * (1 + x / 2), np.expm1(x) / safe)
    dK = np.where(small, dt * dt / 2 * (1 + x / 1.5), (E * dt - K) / safe)
    den = np.exp(2j * np.pi * f * dt)[:, None] - E[None, :]
    return K[None, :] / den, dK[None, :] / den + K[None, :] * dt * E[None, :] / den**2


def _gaps(lam, dt):
    """(lam_i - lam_j, nearly-equal mask, safe divisor) of :func:`_fdk_term`, once per modal form."""
    gap = lam[:, None] - lam[None, :]
    scale = np.maximum(np.maximum(np.abs(lam)[:, None], np.abs(lam)[None, :]), 1.0 / dt)
    close = np.abs(gap) <= _CLOSE * scale
    return gap, close, np.where(close, 1.0, gap)


def _fdk_term(lam, val, der, q, dt, gaps=None) -> np.ndarray:
    """sum_ij q_ij F_ij per frequency, F the divided differences of f (module docstring).

    Continuous: F_ij = f_i f_j exactly, so the sum is the quadratic form (val q) . val.
    ZOH: F_ij = (f_i - f_j) / (lam_i - lam_j) off the diagonal, f'_i on it (and on nearly
    equal pairs), which splits into O(F n) sums. ``gaps``: :func:`_gaps` (lam, dt) when the
    caller has them (one per parameter otherwise)."""
    if dt is None:
        return ((val @ q) * val).sum(axis=1)
    _, close, divisor = _gaps(lam, dt) if gaps is None else gaps
    Q = np.where(close, 0.0, q / divisor)
    out = val @ Q.sum(axis=1) - val @ Q.sum(axis=0)
    for i, j in zip(*np.nonzero(close)):
        out = out + q[i, j] * 0.5 * (der[:, i] + der[:, j])
    return out


def _given_response(model, theta, f: np.ndarray, dt: float | None, jacobian: bool = False):
    """H (and dH/dtheta as (F, p)) of a model defined by its frequency response; sampled with
    a zero-order hold (times e^{-i pi f h} sinc(f h), aliases neglected) when ``dt`` is given."""
    theta = np.asarray(theta, dtype=float)
    s = 2j * np.pi * f
    hold = 1.0 if dt is None else hold_response(f, dt, "zoh")
    if not jacobian:
        return model.frequency_response(theta, s) * hold
    H, dH = model.frequency_response_jacobian(theta, s)
    return H * hold, np.ascontiguousarray((np.atleast_2d(dH) * hold).T)


def response(model: MediumModel, theta, f, dt: float | None = None) -> np.ndarray:
    """H(f): continuous (``dt`` None) or ZOH-sampled at interval ``dt`` [s]."""
    f = np.atleast_1d(np.asarray(f, dtype=float))
    if not getattr(model, "has_state_space", True):
        return _given_response(model, theta, f, dt)
    ss, mf = _system(model, np.asarray(theta, dtype=float))
    if mf is None or mf.kappa > MODAL_MAX_CONDITION:
        return _direct_response(ss, f, dt)
    val, der = _point_values(mf.lam, f, dt)
    r = (mf.cb * mf.bb)[None, :]
    terms = val * r
    H = mf.d + terms.sum(axis=1)
    bad = _cancelling(terms, H, der * r, mf.kappa, _balanced_norm(ss, mf))
    if bad.any():  # modal terms cancel to round-off there: solve those frequencies directly
        H[bad] = _direct_response(ss, f[bad], dt)
    return H


def response_batch(model: MediumModel, thetas, f, dt: float | None = None, block: int = 64) -> np.ndarray:
    """H for many parameter vectors in one call: ``thetas`` (S, p), ``f`` (F,) shared or
    (S, F) one grid per vector [Hz]; returns (S, F), equal to :func:`response` row by row.

    The same two paths as :func:`response`, vectorised over the batch: the balanced
    eigendecompositions of all state matrices in one stacked ``np.linalg.eig`` / ``inv``, the
    modal sums for every (vector, frequency) at once, and every (vector, frequency) pair whose
    modal terms cancel (or whose eigenvectors are ill conditioned) in stacked LU solves of
    s I - A (:func:`_solved_pairs`; continuous; sampled responses solve those per vector). Only the model's own
    state-space arithmetic runs once per vector; ``block`` vectors at a time bound the memory."""
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    f = np.asarray(f, dtype=float)
    S = thetas.shape[0]
    fs = np.broadcast_to(f, (S, f.shape[-1]))
    if not getattr(model, "has_state_space", True) or S == 0:
        return np.array([response(model, th, fs[k], dt) for k, th in enumerate(thetas)]).reshape(S, fs.shape[1])
    if S > block:
        return np.vstack([response_batch(model, thetas[a : a + block], fs[a : a + block], dt, block)
                          for a in range(0, S, block)])
    systems = [as_float_ss(model.state_space(th)) for th in thetas]
    H = np.full(fs.shape, np.nan, dtype=complex)
    bad = np.ones(fs.shape, dtype=bool)
    modal = _modal_batch(systems)
    if modal is not None:
        ok, lam, cb, bb, d, kappa, norm = modal
        if ok.any():
            val, der = _point_values_batch(lam[ok], fs[ok], dt)
            r = (cb[ok] * bb[ok])[:, None, :]
            terms = val * r
            Hm = d[ok, None] + terms.sum(axis=2)
            H[ok] = Hm
            bad[ok] = _cancelling(terms, Hm, der * r, kappa[ok], norm[ok])
    rows = np.flatnonzero(bad.any(axis=1))
    if rows.size == 0:
        return H
    if dt is not None:
        for k in rows:
            H[k, bad[k]] = _direct_response(systems[k], fs[k, bad[k]], dt)
        return H
    balanced = [_balanced(systems[k])[0] for k in rows]
    A = np.array([b.A for b in balanced])
    B = np.array([b.B[:, 0] for b in balanced]).astype(complex)
    C = np.array([b.C[0] for b in balanced]).astype(complex)
    D = np.array([b.D[0, 0] for b in balanced])
    which, col = np.nonzero(bad[rows])  # pairs (row of ``rows``, frequency)
    H[rows[which], col] = _solved_pairs(A, B, C, which, 2j * np.pi * fs[rows[which], col]) + D[which]
    return H


def _solved_pairs(A, B, C, which, s, chunk: int = 2048) -> np.ndarray:
    """C_w (s_k I - A_w)^-1 B_w for the pairs k (w = ``which[k]``) by stacked LU solves, ``chunk``
    pairs at a time: the (pairs, n, n) stack of a whole scan (tens of thousands of pairs)
    would take hundreds of MB, fresh pages on every call."""
    d = np.arange(A.shape[1])
    out = np.empty(s.size, dtype=complex)
    for a in range(0, s.size, chunk):
        w = which[a : a + chunk]
        M = np.negative(A[w], dtype=complex)
        M[:, d, d] += s[a : a + chunk, None]
        x = np.linalg.solve(M, B[w][..., None])[..., 0]
        out[a : a + chunk] = np.einsum("kn,kn->k", x, C[w])
    return out


def _modal_batch(systems: list[StateSpace]):
    """(usable, lam, cb, bb, d, kappa, ||A||_1) of the balanced eigendecompositions of ``systems`` (as
    :func:`~mbus_framework.engine.simulation.modal_form`, stacked), or None."""
    from scipy.linalg.lapack import dgebal

    S, n = len(systems), systems[0].A.shape[0]
    if n == 0:
        return None
    usable = np.array([bool(np.all(np.isfinite(s.A))) for s in systems])
    Ab = np.tile(np.eye(n), (S, 1, 1))
    scale = np.ones((S, n))
    for k, s in enumerate(systems):
        if usable[k]:
            a, _, _, sc, info = dgebal(s.A, scale=1, permute=0)
            usable[k] = info == 0
            Ab[k], scale[k] = (a, sc) if info == 0 else (np.eye(n), 1.0)
    try:
        lam, V = np.linalg.eig(Ab)
        W = np.linalg.inv(V)
    except np.linalg.LinAlgError:  # one singular stack member: per system, as modal_form does
        forms = [modal_form(s) if u else None for s, u in zip(systems, usable)]
        usable &= np.array([m is not None and m.kappa <= MODAL_MAX_CONDITION for m in forms])
        z = np.zeros((S, n), dtype=complex)
        lam, cb, bb, kappa, norm = z.copy(), z.copy(), z.copy(), np.ones(S), np.zeros(S)
        for k, m in enumerate(forms):
            if usable[k]:
                lam[k], cb[k], bb[k], kappa[k] = m.lam, m.cb, m.bb, m.kappa
                norm[k] = _balanced_norm(systems[k], m)
        return usable, lam, cb, bb, np.array([s.D[0, 0] for s in systems], dtype=float), kappa, norm
    lam, V = np.asarray(lam, dtype=complex), np.asarray(V, dtype=complex)
    usable &= np.isfinite(W).all(axis=(1, 2))
    kappa = np.abs(V).sum(axis=1).max(axis=1) * np.abs(W).sum(axis=1).max(axis=1)
    usable &= kappa <= MODAL_MAX_CONDITION
    C = np.array([s.C[0] for s in systems], dtype=float)
    B = np.array([s.B[:, 0] for s in systems], dtype=float)
    cb = np.einsum("si,sij->sj", C * scale, V)
    bb = np.einsum("sij,sj->si", W, B / scale)
    norm = np.abs(Ab).sum(axis=1).max(axis=1)
    return usable, lam, cb, bb, np.array([s.D[0, 0] for s in systems], dtype=float), kappa, norm


def _point_values_batch(lam: np.ndarray, f: np.ndarray, dt: float | None):
    """f(lam) and f'(lam) per (vector, frequency, mode), shape (S, F, n) (:func:`_point_values` stacked)."""
    if dt is None:
        val = 1.0 / (2j * np.pi * f[:, :, None] - lam[:, None, :])
        return val, val**2
    pairs = [_point_values(lk, fk, dt) for lk, fk in zip(lam, f)]
    return np.array([v for v, _ in pairs]), np.array([d for _, d in pairs])


def response_with_jacobian(model: MediumModel, theta, f, dt: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(H (F,), dH/dtheta (F, p)) at frequencies ``f`` [Hz]; see the module docstring."""
    theta = np.asarray(theta, dtype=float)
    f = np.atleast_1d(np.asarray(f, dtype=float))
    if not getattr(model, "has_state_space", True):
        return _given_response(model, theta, f, dt, jacobian=True)
    ss, mf = _system(model, theta)
    if mf is None or mf.kappa > MODAL_MAX_CONDITION:
        return _direct_jacobian(model, theta, f, dt, ss)
    val, der = _point_values(mf.lam, f, dt)
    r = (mf.cb * mf.bb)[None, :]
    terms = val * r
    H = mf.d + terms.sum(axis=1)
    bad = _cancelling(terms, H, der * r, mf.kappa, _balanced_norm(ss, mf))
    derivatives = [tuple(np.atleast_2d(np.asarray(m, dtype=float)) for m in dss)
                   for dss in state_space_derivatives(model, theta)]
    if bad.all():
        return _direct_jacobian(model, theta, f, dt, ss, derivatives)
    T = mf.scale
    J = np.empty((f.size, theta.size), dtype=complex)
    gaps = None if dt is None else _gaps(mf.lam, dt)
    for p, (dA, dB, dC, dD) in enumerate(derivatives):
        dcb = (dC[0] * T) @ mf.V
        dbb = mf.W @ (dB[:, 0] / T)
        M = mf.W @ ((dA * T[None, :]) / T[:, None]) @ mf.V
        q = mf.cb[:, None] * M * mf.bb[None, :]
        J[:, p] = (
            (val * (dcb * mf.bb + mf.cb * dbb)[None, :]).sum(axis=1)
            + _fdk_term(mf.lam, val, der, q, dt, gaps)
            + float(dD[0, 0])
        )
    if bad.any():  # the lines where the modal sum is unsafe: solved directly
        H[bad], J[bad] = _direct_jacobian(model, theta, f[bad], dt, ss, derivatives)
    return H, J


def _cancelling(terms: np.ndarray, H: np.ndarray, slopes=None, kappa=1.0, norm=0.0, limit: float = 1e3,
                tol: float = PEAK_TOLERANCE) -> np.ndarray:
    """Lines where the modal sum H_k = sum_i t_ik, t_ik = r_i f(lam_i), is unsafe; shape of ``H``.

    A line is safe when the sum loses at most log10(``limit``) digits of its own value,
    sum_i |t_ik| <= limit |H_k|, or when its first-order error bound

        e_k = eps kappa (sum_i |t_ik| + ||A|| sum_i |r_i f'(lam_i)|)

    (round-off of the sum, and eigenvalues perturbed by eps kappa ||A||; ``slopes`` the
    r_i f'(lam_i), ``norm`` ||A|| of the balanced matrix, ``kappa`` the eigenvector condition
    number) is at most ``tol`` P, P the peak |H_j| of the lines with e_j <= tol |H_j|: a
    heavily attenuating chain's response decades below its modes comes from the modal sum
    accurate to ``tol`` of its peak; a nearly defective model (no line accurate) is solved
    directly. ``terms``, ``slopes`` (..., F, n); ``kappa``, ``norm`` scalars or one per leading index."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        size, mag = np.abs(terms).sum(axis=-1), np.abs(H)
        k, a = (np.asarray(x, dtype=float)[..., None] for x in (kappa, norm))
        drift = 0.0 if slopes is None else a * np.abs(slopes).sum(axis=-1)
        bound = np.finfo(float).eps * k * (size + drift)
        reliable = (bound <= tol * mag) & np.isfinite(mag)
        peak = np.max(np.where(reliable, mag, 0.0), axis=-1, keepdims=True)
        return ~((size <= limit * mag) | (bound <= tol * peak))


def _balanced_norm(ss, mf) -> float:
    """1-norm of the balanced state matrix T^-1 A T of a modal form."""
    return float(np.abs(ss.A * mf.scale[None, :] / mf.scale[:, None]).sum(axis=0).max())


def _solve_points(ss, f: np.ndarray, dt: float | None):
    """Points s (continuous) or z (sampled) and the matrices (A, B) they are solved against."""
    A, B, C, D = ss
    if dt is None:
        return 2j * np.pi * f, A, B
    from mbus_framework.engine.simulation import discretize

    sys = discretize(ss, float(dt), "zoh")
    return np.exp(2j * np.pi * f * float(dt)), sys.Phi, sys.Gamma.reshape(-1, 1)


def _resolvent(s: np.ndarray, A: np.ndarray) -> np.ndarray:
    """(F, n, n) stack of s_k I - A."""
    n = A.shape[0]
    M = np.empty((s.size, n, n), dtype=complex)
    M[...] = -A
    d = np.arange(n)
    M[:, d, d] += s[:, None]
    return M


def _direct_response(ss, f: np.ndarray, dt: float | None) -> np.ndarray:
    """One batched solve per frequency (safe for defective models), in the balanced basis."""
    ss, _ = _balanced(ss)
    s, A, B = _solve_points(ss, f, dt)
    M = _resolvent(s, A)
    x = np.linalg.solve(M, np.broadcast_to(B.astype(complex), (s.size, A.shape[0], 1)))[..., 0]
    return x @ ss.C[0].astype(complex) + ss.D[0, 0]


def _balanced(ss, *derivatives):
    """The system and its derivatives in the diagonally balanced basis T^-1 A T, T^-1 B, C T
    (the response is unchanged; the exponential of a badly scaled A loses digits)."""
    from scipy.linalg import matrix_balance

    if np.all(np.isfinite(ss.A)):
        _, (t, _) = matrix_balance(ss.A, permute=False, separate=True)
    else:  # a trial point outside the model's domain: let the solve return NaN as before
        t = np.ones(ss.A.shape[0])

    def to(m):
        A, B, C, D = (np.atleast_2d(np.asarray(x, dtype=float)) for x in m)
        return StateSpace(A * t[None, :] / t[:, None], B / t[:, None], C * t[None, :], D)

    return to(ss), [to(d) for d in derivatives]


def _direct_jacobian(model, theta, f, dt, ss=None, derivatives=None) -> tuple[np.ndarray, np.ndarray]:
    """Exact (H, dH/dtheta) by a direct solve and its adjoint (module docstring); ``ss`` and
    ``derivatives`` (:func:`state_space_derivatives`) when the caller has them."""
    from scipy.linalg import expm_frechet

    if ss is None:
        ss = as_float_ss(model.state_space(theta))
    if derivatives is None:
        derivatives = state_space_derivatives(model, theta)
    ss, derivatives = _balanced(ss, *derivatives)
    s, A, B = _solve_points(ss, f, dt)
    n = A.shape[0]
    M = _resolvent(s, A)
    x = np.linalg.solve(M, np.broadcast_to(B.astype(complex), (s.size, n, 1)))[..., 0]
    w = np.linalg.solve(np.transpose(M, (0, 2, 1)), np.broadcast_to(ss.C[0].astype(complex), (s.size, n))[..., None])[
        ..., 0
    ]
    H = x @ ss.C[0].astype(complex) + ss.D[0, 0]
    J = np.empty((f.size, theta.size), dtype=complex)
    for p, (dA, dB, dC, dD) in enumerate(derivatives):
        if dt is not None:  # derivative of [[Phi, Gamma0], [0, 1]] = expm([[A h, B h], [0, 0]])
            h = float(dt)
            aug = np.zeros((n + 1, n + 1))
            aug[:n, :n], aug[:n, n:] = ss.A * h, ss.B * h
            daug = np.zeros((n + 1, n + 1))
            daug[:n, :n], daug[:n, n:] = dA * h, dB * h
            dE = expm_frechet(aug, daug, compute_expm=False)
            dA, dB = dE[:n, :n], dE[:n, n:]
        J[:, p] = x @ dC[0] + ((w @ dA) * x).sum(axis=1) + w @ dB[:, 0] + dD[0, 0]
    return H, J


def tail_basis(model: MediumModel, theta, f, dt: float, n_samples: int) -> np.ndarray:
    """(F, n) transforms of the free responses that continue past the end of a record.

    A record y[0..N-1] of a system started at rest differs from the transform of its
    never-ending response by the tail y[N + m] = C Phi^m x_N (Phi = e^{Ah}), whose transform is

        e^{-i w N} C (I - Phi e^{-i w})^-1 x_N = sum_k x_N,k b_k(w),   w = 2 pi f h,

    linear in the unknown end state x_N. Column k is b_k; modal form when safe, else a direct
    solve per frequency."""
    theta = np.asarray(theta, dtype=float)
    f = np.atleast_1d(np.asarray(f, dtype=float))
    # no states: the record's tail is not modelled (the solver drops transient periods)
    if not getattr(model, "has_state_space", True):
        return np.zeros((f.size, 0), dtype=complex)
    ss, mf = _system(model, theta)
    w = 2 * np.pi * f * dt
    shift = np.exp(-1j * w * n_samples)[:, None]
    if mf is not None and mf.kappa <= MODAL_MAX_CONDITION:
        E = np.exp(np.clip((mf.lam * dt).real, None, 700) + 1j * (mf.lam * dt).imag)
        modal = 1.0 / (1.0 - E[None, :] * np.exp(-1j * w)[:, None])
        coupling = (mf.cb[:, None] * mf.W) / mf.scale[None, :]  # cb_i (W T^-1)_ik
        return shift * (modal @ coupling)
    from mbus_framework.engine.simulation import discretize

    Phi = discretize(ss, float(dt), "zoh").Phi
    n = Phi.shape[0]
    M = np.eye(n)[None] - Phi[None] * np.exp(-1j * w)[:, None, None]
    rhs = np.broadcast_to(ss.C[0].astype(complex), (f.size, n))[..., None]  # stacked vectors (numpy 2)
    rows = np.linalg.solve(np.transpose(M, (0, 2, 1)), rhs)[..., 0]
    return shift * rows
