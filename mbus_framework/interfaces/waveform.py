"""A sampled waveform and its spectrum: :class:`Waveform`, :class:`Spectrum`, :func:`power_spectrum`,
:func:`crest_factor` (numpy only).

Part of the excitation interface (:mod:`mbus_framework.interfaces.excitation` re-exports every
name); a module of its own so that what only reads waveforms (the run's figures, drawn by a
helper process forked before pydantic loads) does not import the plugin machinery.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Waveform:
    """A sampled excitation: times t [s] (uniform, from 0) and values u (amplitude units)."""

    t: np.ndarray
    u: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def sample_rate(self) -> float:
        return 1.0 / self.dt


@dataclass(frozen=True)
class Spectrum:
    """One-sided power spectrum: frequencies f [Hz], power density (arbitrary units)."""

    f: np.ndarray
    power: np.ndarray

    def bandwidth_3db(self) -> float:
        """Frequency [Hz] above which the power stays below half its low-frequency peak.

        For a PRBS of bit width T_b the envelope is sinc^2(f T_b), so this is about
        0.443 / T_b (Fig. 3.7).
        """
        p = self.power
        peak = p.max()
        below = np.nonzero(p >= peak / 2.0)[0]
        return float(self.f[below[-1]]) if below.size else 0.0

    def band_3db(self) -> tuple[float, float]:
        """(lowest, highest) frequency [Hz] whose power is at least half the peak power.

        For a low-pass spectrum (PRBS) the lower edge is the first line; for a sweep or a
        multisine it is the start of the covered band.
        """
        p = self.power
        keep = np.nonzero(p >= p.max() / 2.0)[0]
        if not keep.size:
            return 0.0, 0.0
        return float(self.f[keep[0]]), float(self.f[keep[-1]])


def power_spectrum(u: np.ndarray, dt: float) -> Spectrum:
    """Periodogram of ``u`` (mean removed), frequencies up to Nyquist."""
    u = np.asarray(u, dtype=float) - np.mean(u)
    U = np.fft.rfft(u)
    f = np.fft.rfftfreq(len(u), dt)
    return Spectrum(f, (np.abs(U) ** 2) * dt / len(u))


def crest_factor(u: np.ndarray) -> float:
    """Crest factor max|u| / RMS(u) (dimensionless): 1 for a PRBS, sqrt(2) for a sine or a chirp."""
    u = np.asarray(u, dtype=float)
    rms = float(np.sqrt(np.mean(np.square(u)))) if u.size else 0.0
    return float(np.max(np.abs(u)) / rms) if rms > 0 else float("inf")
