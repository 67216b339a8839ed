"""Causal convolution of the kernels of eq. (1) with the input record, by FFT.

O(N log N); the input spectrum is cached, so refitting the same record costs one forward and
one inverse transform per output.
"""
from __future__ import annotations

import numpy as np
from scipy import fft as sfft


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


def respond(g: np.ndarray, corr: np.ndarray | None, u: np.ndarray) -> np.ndarray:
    """Eq. (1): causal convolution with the kernels g (..., N) minus u[0] times corr."""
    y = causal_convolve(g, u)
    if corr is not None and u.shape[-1]:
        y -= u[0] * corr
    return y
