"""Outputs and sensitivities of eq. (1) from the modal form, with their round-off bounds.

Kernels (:func:`modal_kernels`): the power table e^{z_i j} is built blockwise (exp of z_i r and
of z_i b K, one matrix product), so the kernels cost O(n N) without forming Phi^k. The output
alone (:func:`modal_block_response`) uses a block recursion over the modal states (blocks of 32
samples, a Toeplitz product inside each block, a prefix scan over block-start states; O(N),
no FFT).

Sensitivities. In modal coordinates (A~_p = V^-1 A_p V, q_ij = c~_i A~_p,ij b~_j) the
continuous impulse response of dy/dtheta_p is

    h_p(t) = sum_i (r'_i + alpha_i) e^{lambda_i t} + q_ii t e^{lambda_i t},
    r'_i = (C_p V)_i b~_i + c~_i (V^-1 B_p)_i,
    alpha_i = sum_{j != i} (q_ij + q_ji) / (lambda_i - lambda_j)

(the divided differences (e^{lambda_i t} - e^{lambda_j t}) / (lambda_i - lambda_j) of the
Frechet derivative of e^{A t}, split into partial fractions). Integrating against the hold
kernel gives

    g_p[m] = Re sum_i w_i e^{z_i (m-1)} [(r'_i + alpha_i) K_i + q_ii (dK/dlambda)_i + (m-1) h q_ii K_i],

and likewise for c_p; dK/dlambda uses phi_1' = phi_1 - phi_2, phi_2' = phi_2 - 2 phi_3.

Round-off: every modal sum carries an absolute error ~eps times its termwise bound; the
amplification of that bound in the outputs (:func:`output_amplification`) decides, in
:mod:`mbus_framework.engine.simulation`, whether the modal result is kept.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from mbus_framework.engine.doubling import Hold
from mbus_framework.engine.modal import ModalForm, hold_weights
from mbus_framework.engine.small_products import small_matmul


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
    # R stacks of small products (single-threaded BLAS calls, see small_matmul); (R, nb, K) is
    # already the row-major layout of (R, nb K)
    return small_matmul(left, right).reshape(R, nb * K)[:, :count]


def modal_kernels(mf: ModalForm, dt: float, hold: Hold, N: int, derivs=None):
    """Kernels g (1+p, N) and, for FOH, c (1+p, N) of eq. (1) by the modal formulas, with
    the bounds sum_i max_j |term_i(j)| of their modal sums per row (see ``_term_bounds``)."""
    lam = mf.lam
    z = lam * dt
    K, dK, L, dL = hold_weights(z, dt, hold, derivs is not None)
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
        At = small_matmul(small_matmul(mf.W, Ap, rows=32), mf.V, rows=32)  # (p, n, n) modal A_p
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


def output_amplification(out: np.ndarray, gbound: np.ndarray, cbound, u: np.ndarray) -> float:
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


def modal_block_response(mf: ModalForm, dt: float, hold: Hold, u: np.ndarray) -> tuple[np.ndarray, float]:
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

    Returns y and its round-off amplification (:func:`output_amplification`).
    """
    N = u.shape[-1]
    k, w = mf.keep, mf.weight
    z = mf.lam[k] * dt
    K, _, Lh, _ = hold_weights(mf.lam * dt, dt, hold, derivatives=False)
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
    Y = small_matmul(U, T)
    if nb > 1 or hold == "foh":
        srev = small[:, L - 1 :: -1]  # mu^(L-1-r), r = 0..L-1   (n, L)
        S2 = small_matmul(U, np.concatenate([srev.real, srev.imag], axis=0).T)  # (nb, 2n)
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
        Y += small_matmul(np.concatenate([M.real, M.imag], axis=1), np.concatenate([small[:, :L].real, -small[:, :L].imag], axis=0))
    y = Y.reshape(-1)[:N]
    grow = np.where(z.real > 0, np.exp(z.real * (N - 1)), 1.0)  # max_j |mu^j|
    gbound = float(np.abs(a) @ grow)
    cbound = None
    if hold == "foh":  # c enters twice: in g[0] (times every u[k]) and in the start term
        cbound = float(np.abs(c0) @ grow)
        gbound += cbound
    return y, output_amplification(y, gbound, cbound, u)


def modal_y_bounds(mf: ModalForm, dt: float, hold: Hold, N: int) -> tuple[float, float | None]:
    """Termwise bounds (g, c) of the modal sums of y, as :func:`modal_block_response` forms them."""
    k, w = mf.keep, mf.weight
    z = mf.lam[k] * dt
    K, _, Lh, _ = hold_weights(mf.lam * dt, dt, hold, derivatives=False)
    r = w * (mf.cb * mf.bb)[k]
    grow = np.where(z.real > 0, np.exp(z.real * (N - 1)), 1.0)
    gbound = float(np.abs(r * K[k]) @ grow)
    cbound = None
    if hold == "foh":
        cbound = float(np.abs(r * Lh[k]) @ grow)
        gbound += cbound
    return gbound, cbound
