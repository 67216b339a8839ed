"""Records through models defined by their frequency response: exact FFT convolution.

For a :class:`~mbus_framework.interfaces.model.FrequencyResponseModel` with transfer function
H(s; theta) and an input u[0..N-1] held between samples (ZOH or FOH, hold response P(f)), the
sampled output from rest is

    y = IDFT_n( H(i 2 pi f_m) P(f_m) U_m )[0..N-1],   U = DFT_n(u zero-padded to n),

on the grid f_m = m / (n h), n >= 4 N. With the padding, circular convolution equals linear
convolution up to the part of the impulse response beyond 3 N samples (the model must be causal
and its response have died out by then; lumped chains need none of this, see
:mod:`mbus_framework.engine.simulation`). Sensitivities come the same way from the model's exact
dH/dtheta, so dy/dtheta is exact too. An input gain g and a delay tau multiply the spectrum by
g e^{-s tau}, whose derivatives are e^{-s tau} H P U and -s g e^{-s tau} H P U.
"""
from __future__ import annotations

import numpy as np
from scipy import fft as sfft

from mbus_framework.engine.hold import hold_response

PADDING = 4  # FFT length >= PADDING * N


def _grid(u: np.ndarray, dt: float, hold: str) -> tuple[int, np.ndarray, np.ndarray]:
    """(n, s = i w on the rfft grid, hold response times U)."""
    N = u.shape[-1]
    n = sfft.next_fast_len(PADDING * max(N, 1), real=True)
    f = sfft.rfftfreq(n, dt)
    return n, 2j * np.pi * f, hold_response(f, dt, hold) * sfft.rfft(u, n)


def simulate_response(model, theta, u: np.ndarray, dt: float, hold: str = "zoh",
                      gain: float = 1.0, delay: float = 0.0) -> np.ndarray:
    """Output y (N,) of ``model`` for input u (N,) at interval ``dt`` [s], from rest."""
    u = np.asarray(u, dtype=float)
    n, s, PU = _grid(u, dt, hold)
    G = gain * model.frequency_response(np.asarray(theta, dtype=float), s)
    if delay:
        G = G * np.exp(-s * delay)
    return sfft.irfft(G * PU, n)[: u.size]


def simulate_response_with_sensitivities(model, theta, u: np.ndarray, dt: float, hold: str = "zoh",
                                         gain: float = 1.0, delay: float | None = None):
    """(y (N,), dy/dtheta (N, p)); with ``delay`` given (nuisance active) also dy/dgain (N,)
    and dy/dtau (N,)."""
    u = np.asarray(u, dtype=float)
    n, s, PU = _grid(u, dt, hold)
    H, dH = model.frequency_response_jacobian(np.asarray(theta, dtype=float), s)
    shift = np.exp(-s * delay) if delay else 1.0
    base = H * shift * PU
    rows = np.vstack([gain * base, gain * np.atleast_2d(dH) * shift * PU])
    if delay is not None:
        rows = np.vstack([rows, base, -s * gain * base])
    out = sfft.irfft(rows, n, axis=-1)[:, : u.size]
    p = np.atleast_2d(dH).shape[0]
    y, J = out[0], np.ascontiguousarray(out[1 : 1 + p].T)
    if delay is None:
        return y, J
    return y, J, out[1 + p], out[2 + p]
