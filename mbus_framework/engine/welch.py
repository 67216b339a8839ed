"""Welch's averaged (cross-)periodogram in numpy alone (scipy.signal's default settings,
without importing scipy.signal, whose import costs a single run about half a second).

Segments of L samples overlapping by L/2 (floor), each with its own mean removed and a periodic
Hann window w; X_m, Y_m their DFTs. The one-sided cross spectral density [unit_x unit_y / Hz] is

    P_xy(f_k) = c_k h / sum(w^2) * mean_m conj(X_m[k]) Y_m[k],   f_k = k / (L h),

c_k = 2 except at DC (and Nyquist for even L), where c_k = 1. P_xx is the power spectral density.
Equal to scipy.signal.csd / welch with their defaults (tested).
"""
from __future__ import annotations

import numpy as np


def cross_spectral_density(x: np.ndarray, y: np.ndarray, dt: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """(f [Hz], P_xy) of two equally long records sampled at interval ``dt`` [s]."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    L = int(min(nperseg, x.size))
    starts = np.arange(0, x.size - L + 1, L - L // 2)
    window = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(L) / L)
    index = starts[:, None] + np.arange(L)

    def spectra(a):
        seg = a[index]
        return np.fft.rfft((seg - seg.mean(axis=1, keepdims=True)) * window, axis=1)

    X = spectra(x)
    Y = X if y is x else spectra(y)
    P = np.mean(np.conj(X) * Y, axis=0) * dt / np.sum(window**2)
    P[1 : (L + 1) // 2] *= 2
    return np.fft.rfftfreq(L, dt), P


def power_spectral_density(x: np.ndarray, dt: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """(f [Hz], P_xx [unit^2/Hz]) (module docstring)."""
    f, P = cross_spectral_density(x, x, dt, nperseg)
    return f, P.real
