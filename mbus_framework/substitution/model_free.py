"""Model-free phase velocity and attenuation from the spectral ratio alone.

Per line, solve P log T(k) = ln(S/R) for the plate's wavenumber k (:mod:`.plate`, impedance
Zs = rho w / k), by Newton's method from the direct-wave estimate

    k = k0 + i (ln(S/R) / P - ln T0) / h,   T0 = 4 Zw Zs / (Zw + Zs)^2,

so internal reverberations are inverted, not left as ripple. c = w / Re k, alpha = -Im k.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mbus_framework.engine.continuum_laws import velocity_attenuation
from mbus_framework.substitution.spectra import Spectra, unwrapped_log_ratio
from mbus_framework.substitution.water import Water

NP_TO_DB_PER_CM = 20 / np.log(10) / 100


@dataclass
class Dispersion:
    """Phase velocity [m/s] and attenuation [Np/m] against frequency [Hz]."""

    f: np.ndarray
    velocity: np.ndarray
    attenuation: np.ndarray

    @property
    def attenuation_dB_per_cm(self) -> np.ndarray:
        return self.attenuation * NP_TO_DB_PER_CM

    def at(self, f0: float) -> tuple[float, float]:
        """(c [m/s], alpha [dB/cm]) interpolated at f0 [Hz]."""
        return float(np.interp(f0, self.f, self.velocity)), float(np.interp(f0, self.f, self.attenuation_dB_per_cm))


def _log_transmission(k, w, rho, h, water: Water, reverberations: bool):
    Zs = rho * w / k
    Zw = water.impedance
    out = np.log(4 * Zw * Zs) - 2 * np.log(Zw + Zs) - 1j * (k - w / water.speed) * h
    if reverberations:
        out = out - np.log(1 - ((Zw - Zs) / (Zw + Zs)) ** 2 * np.exp(-2j * k * h))
    return out


def model_free(sp: Spectra, rho: float, h: float, water: Water, passes: int = 2, reverberations: bool = True) -> Dispersion:
    L = unwrapped_log_ratio(sp) / passes
    w = sp.w
    k0 = w / water.speed
    k = k0 + 0j
    for _ in range(3):  # direct-wave estimate, impedance refined
        Zs = rho * w / np.where(k.real > 0, k, k0)
        logT0 = np.log(4 * water.impedance * Zs) - 2 * np.log(water.impedance + Zs)
        k = k0 + 1j * (L - logT0) / h
    if reverberations:
        for _ in range(30):  # Newton on g(k) = log T(k) - L, complex-differentiable
            g = _log_transmission(k, w, rho, h, water, True) - L
            dk = 1e-7 * np.abs(k)
            dg = (_log_transmission(k + dk, w, rho, h, water, True) - _log_transmission(k - dk, w, rho, h, water, True)) / (2 * dk)
            step = g / dg
            k = k - step * np.minimum(1.0, 0.2 * np.abs(k) / np.maximum(np.abs(step), 1e-300))
            if np.max(np.abs(step) / np.abs(k)) < 1e-12:
                break
    c, alpha = velocity_attenuation(k, w)
    return Dispersion(sp.f, c, alpha)
