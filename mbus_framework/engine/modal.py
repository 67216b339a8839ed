"""Balanced eigendecomposition of a continuous SISO system and the hold weights of its modes.

A is balanced (T^-1 A T, T diagonal powers of two) and diagonalised, A = V diag(lambda) V^-1.
With c~ = C V, b~ = V^-1 B, residues r_i = c~_i b~_i and z_i = lambda_i h (h = ``dt`` [s]),
every kernel of eq. (1) (:mod:`mbus_framework.engine.simulation`) is a sum of modes

    g[m] = Re sum_i w_i r_i K(z_i) e^{z_i (m-1)},   c[k] = Re sum_i w_i r_i h phi_2(z_i) e^{z_i k}

with K = h phi_1(z) (ZOH) or h (phi_1 - phi_2 + e^z phi_2)(z) (FOH); w_i = 2 for one member of
each complex-conjugate pair, 1 for real eigenvalues (the partner is dropped).
phi_1(z) = (e^z - 1)/z, phi_2(z) = (e^z - 1 - z)/z^2, phi_3(z) = (e^z - 1 - z - z^2/2)/z^3.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgebal

from mbus_framework.engine.doubling import Hold
from mbus_framework.interfaces.model import StateSpace


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


def hold_weights(z: np.ndarray, dt: float, hold: Hold, derivatives: bool = True):
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
