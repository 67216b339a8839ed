"""Frequency-domain filters of records, used by compensators and the excitation design.

:class:`SpectralFilter` (a frequency
response applied to records along axis 0, with its exact transpose) and
:func:`coloured_noise_standard_errors` (sandwich standard errors when the fitted record's noise
has passed a known linear filter).
"""
from __future__ import annotations

from typing import Callable

import numpy as np
from scipy import fft as sfft


# ---------------------------------------------------------------------------------------------
# Frequency-domain filters of records (used by compensators and excitation design)
# ---------------------------------------------------------------------------------------------
class SpectralFilter:
    """x -> first n samples of IFFT(H(f) FFT(x zero-padded to nfft >= 2n)), along axis 0.

    ``response(f)`` gives H on the rfft grid; it is evaluated once per (n, dt).
    """

    def __init__(self, response: Callable[[np.ndarray], np.ndarray]):
        self.response = response
        self._cache: dict[tuple[int, float], tuple[int, np.ndarray]] = {}

    def gain(self, n: int, dt: float) -> tuple[int, np.ndarray]:
        key = (int(n), float(dt))
        if key not in self._cache:
            nfft = sfft.next_fast_len(2 * n, real=True)
            self._cache[key] = (nfft, np.asarray(self.response(sfft.rfftfreq(nfft, dt)), dtype=complex))
        return self._cache[key]

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        n = x.shape[0]
        nfft, H = self.gain(n, dt)
        X = sfft.rfft(x, nfft, axis=0)
        return sfft.irfft(X * (H if x.ndim == 1 else H[:, None]), nfft, axis=0)[:n]

    def adjoint(self, x: np.ndarray, dt: float) -> np.ndarray:
        """The transpose of this linear map (pad, filter by conj(H), truncate)."""
        x = np.asarray(x, dtype=float)
        n = x.shape[0]
        nfft, H = self.gain(n, dt)
        X = sfft.rfft(x, nfft, axis=0)
        Hc = np.conj(H)
        return sfft.irfft(X * (Hc if x.ndim == 1 else Hc[:, None]), nfft, axis=0)[:n]



def coloured_noise_standard_errors(
    jacobian: np.ndarray, noise_std: float, noise_filter: SpectralFilter | None, dt: float
) -> np.ndarray:
    """Standard errors of a least-squares fit whose noise is sigma * (filter applied to white noise).

    Cov = (J^T J)^-1 J^T Sigma J (J^T J)^-1 with Sigma = sigma^2 F F^T (F the filter as a matrix),
    i.e. sigma^2 (J^T J)^-1 (F^T J)^T (F^T J) (J^T J)^-1; without a filter, sigma^2 (J^T J)^-1.
    ``jacobian``: (N, p) free columns of d yhat / d theta of the fitted problem.
    """
    J = np.asarray(jacobian, dtype=float)
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms
    A = np.linalg.pinv(Js.T @ Js)
    if noise_filter is None:
        cov = noise_std**2 * A
    else:
        FtJ = noise_filter.adjoint(Js, dt)
        cov = noise_std**2 * A @ (FtJ.T @ FtJ) @ A
    return np.sqrt(np.clip(np.diag(cov), 0, None)) / norms
