"""Plane-wave transmission through a plate immersed in water, normal incidence (e^{iwt}).

One pass through a plate of thickness h [m] with wavenumber k and impedance Zs, replacing the
water it displaces (wavenumber k0, impedance Zw):

    T(w) = 4 Zw Zs e^{-i k h} / ((Zw + Zs)^2 - (Zw - Zs)^2 e^{-2 i k h}) * e^{+i k0 h}

(all internal reverberations summed; ``reverberations=False`` keeps only the direct wave,
T = 4 Zw Zs / (Zw + Zs)^2 e^{-i (k - k0) h}). The substitution ratio of the sample shot to the
reference shot is T^P for P passes (P = 2 in double through-transmission).
"""
from __future__ import annotations

import numpy as np


def transmission(k, Zs, k0, Zw: float, h: float, reverberations: bool = True) -> np.ndarray:
    """One-pass transmission T(w) relative to water (module docstring)."""
    k, Zs, k0 = (np.asarray(x, dtype=complex) for x in (k, Zs, k0))
    phase = np.exp(-1j * k * h)
    if reverberations:
        T = 4 * Zw * Zs * phase / ((Zw + Zs) ** 2 - (Zw - Zs) ** 2 * phase**2)
    else:
        T = 4 * Zw * Zs / (Zw + Zs) ** 2 * phase
    return T * np.exp(1j * k0 * h)


def substitution_ratio(M, w, rho: float, h: float, water, passes: int = 2, reverberations: bool = True):
    """S/R = T^P for complex modulus M(w) [Pa] of a plate of density rho [kg/m^3]."""
    from mbus_framework.engine.continuum_laws import wavenumber

    k = wavenumber(M, w, rho)
    Zs = rho * w / k
    k0 = w / water.speed
    return transmission(k, Zs, k0, water.impedance, h, reverberations) ** passes
