"""The shots' spectra on the lines where the reference shot carries energy.

R(f), S(f): numpy's rfft of the shots (kernel e^{-i 2 pi f t}, so a delay tau multiplies by
e^{-i 2 pi f tau} and a wave e^{-i k x} keeps its sign). The band is the contiguous run of lines
around the reference's peak with |R| within ``band_dB`` of that peak.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mbus_framework.substitution.record import SubstitutionRecord


@dataclass
class Spectra:
    f: np.ndarray  # in-band line frequencies [Hz]
    R: np.ndarray  # reference spectrum on those lines
    S: np.ndarray  # sample spectrum on those lines
    delay: float  # cross-correlation delay of the sample shot against the reference [s]

    @property
    def w(self) -> np.ndarray:
        return 2 * np.pi * self.f

    @property
    def ratio(self) -> np.ndarray:
        return self.S / self.R


def spectra(record: SubstitutionRecord, band_dB: float = 30.0) -> Spectra:
    r, s = record.reference - np.mean(record.reference), record.sample - np.mean(record.sample)
    R, S = np.fft.rfft(r), np.fft.rfft(s)
    f = np.fft.rfftfreq(r.size, record.dt)
    mag = np.abs(R)
    peak = int(np.argmax(mag[1:])) + 1
    keep = mag >= mag[peak] * 10 ** (-band_dB / 20)
    lo = hi = peak
    while lo > 1 and keep[lo - 1]:
        lo -= 1
    while hi < f.size - 1 and keep[hi + 1]:
        hi += 1
    if hi - lo + 1 < 5:
        raise ValueError(f"{record.source or 'record'}: the reference shot has fewer than 5 lines within {band_dB} dB of its peak")
    band = slice(lo, hi + 1)
    return Spectra(f[band], R[band], S[band], xcorr_delay(r, s, record.dt))


def xcorr_delay(r: np.ndarray, s: np.ndarray, dt: float) -> float:
    """Lag [s] maximising the cross-correlation of s against r (parabolic peak refinement);
    negative when the sample shot leads."""
    n = r.size
    c = np.fft.irfft(np.fft.rfft(s, 2 * n) * np.conj(np.fft.rfft(r, 2 * n)), 2 * n)
    lags = np.concatenate([np.arange(0, n), np.arange(-n, 0)])
    i = int(np.argmax(c))
    a, b, d = c[i - 1], c[i], c[(i + 1) % c.size]
    den = a - 2 * b + d
    frac = 0.5 * (a - d) / den if den != 0 else 0.0
    return float((lags[i] + frac) * dt)


def unwrapped_log_ratio(sp: Spectra) -> np.ndarray:
    """ln(S/R) with a continuous phase: the cross-correlation delay taken out before unwrapping
    (so the 2 pi ambiguity is fixed by the delay, not by the band's first line) and put back."""
    lin = -sp.w * sp.delay
    residual = np.unwrap(np.angle(sp.ratio * np.exp(-1j * lin)))
    centre = residual.size // 2
    residual -= 2 * np.pi * np.round(residual[centre] / (2 * np.pi))
    return np.log(np.abs(sp.ratio)) + 1j * (lin + residual)
