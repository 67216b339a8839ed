"""The output-noise level of a record without a model: the local polynomial method.

A record y = g * u + e from rest (or with any start) has DFT lines (k = 0 .. N/2)

    Y_k = G_k U_k + T_k + E_k,      E|E_k|^2 = N sigma^2  (white noise of variance sigma^2),

where G is the response and T the transient term (the start and the response still ringing at
the record's end), both smooth functions of frequency away from narrow resonances
(Pintelon, Schoukens et al., "Estimation of nonparametric noise and FRF models for multivariable
systems", MSSP 24, 2010). In a window of w = 2R + 1 lines around line k, G and T are
polynomials of ``degree`` d in the line offset r = -R .. R,

    Y_{k+r} = sum_j (g_j U_{k+r} + t_j) r^j + E_{k+r},

and the least-squares residual of this local fit holds only noise: its energy ||res||^2 has
expectation (w - 2(d + 1)) N sigma^2 (complex lines: (N sigma^2 / 2) chi^2 with 2(w - 2(d + 1))
degrees of freedom), whatever the input, the transient or the response, as long as they are
smooth over w lines. A lightly damped chain rings in lines narrower than a window: there the
local fit fails and its residual holds signal. The median over the windows ignores those
windows (they are a minority), and the median of chi^2 turns it into sigma^2.
"""
from __future__ import annotations

import numpy as np
from scipy import special

#: Half width R of a window (w = 15 lines) and degree d of the local polynomials: 9 complex
#: degrees of freedom per window.
HALF_WIDTH = 7
DEGREE = 2


def local_polynomial_variance(u: np.ndarray, y: np.ndarray, half_width: int = HALF_WIDTH,
                              degree: int = DEGREE, hop: int | None = None) -> float | None:
    """sigma^2 [output units^2] of white output noise in y (module docstring); None when the
    record has fewer than four windows. Windows start every ``hop`` lines (default R + 1: half
    overlapping) over the lines 1 .. N/2 - 1 (DC and Nyquist are real)."""
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    w = 2 * half_width + 1
    dof = w - 2 * (degree + 1)
    U, Y = np.fft.rfft(u), np.fft.rfft(y)
    first = np.arange(1, U.size - 1 - w + 1, hop or half_width + 1)
    if dof < 1 or first.size < 4:
        return None
    lines = first[:, None] + np.arange(w)
    Uw, Yw = U[lines], Y[lines]
    scale = np.sqrt(np.mean(np.abs(Uw) ** 2, axis=1, keepdims=True))
    Uw = Uw / np.where(scale > 0, scale, 1.0)  # columns of a like size (conditioning only)
    powers = (np.arange(-half_width, half_width + 1, dtype=float)[:, None] ** np.arange(degree + 1))
    design = np.concatenate([Uw[:, :, None] * powers, np.broadcast_to(powers, Uw.shape + powers.shape[1:])], axis=2)
    Q = np.linalg.qr(design)[0]  # orthonormal even where U vanishes: the residual keeps `dof` lines
    residual = Yw - np.einsum("kwp,kp->kw", Q, np.einsum("kwp,kw->kp", Q.conj(), Yw))
    energy = np.sum(np.abs(residual) ** 2, axis=1)  # ~ (N sigma^2 / 2) chi^2_{2 dof}
    chi2_median = 2.0 * special.gammaincinv(dof, 0.5)  # median of chi^2 with 2 dof degrees of freedom
    return float(2.0 * np.median(energy) / (chi2_median * y.size))
