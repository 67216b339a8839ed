"""Dispersion of a fitted chain: the phase velocity and attenuation of the longitudinal wave in
the material its normal properties describe, over the band the record's input excites.

k(w) = w sqrt(rho / M(w)) with M from ``model.complex_modulus`` (chains), c = w / Re k [m/s],
alpha = -Im k [Np/m] (reported in dB/cm); standard errors by the delta method from the model
parameters' covariance. The band: lines where the input's spectrum (smoothed) is within 20 dB
of its peak.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from mbus_framework.engine.moving import moving_average

NP_TO_DB_PER_CM = 20 / np.log(10) / 100
BAND_DB = 20.0


def input_band(u: np.ndarray, dt: float, band_dB: float = BAND_DB) -> tuple[float, float] | None:
    """(f_lo, f_hi) [Hz] where the smoothed |U(f)| is within ``band_dB`` of its peak."""
    u = np.asarray(u, dtype=float)
    if u.size < 16:
        return None
    U = np.abs(np.fft.rfft(u - np.mean(u)))
    f = np.fft.rfftfreq(u.size, dt)
    width = max(1, U.size // 200)
    smooth = moving_average(U, width)
    smooth[0] = 0.0
    if not np.any(smooth > 0):
        return None
    inside = np.flatnonzero(smooth >= np.max(smooth) * 10 ** (-band_dB / 20))
    lo, hi = f[inside[0]], f[inside[-1]]
    return (float(max(lo, f[1])), float(hi)) if hi > lo else None


def _curves(model, theta: np.ndarray, f: np.ndarray) -> np.ndarray:
    w = 2 * np.pi * f
    k = w * np.sqrt(model.sample.density / np.asarray(model.complex_modulus(theta, f), dtype=complex))
    k = np.where(k.real < 0, -k, k)
    return np.concatenate([w / k.real, -k.imag * NP_TO_DB_PER_CM])


def dispersion_section(model, theta: np.ndarray, u: np.ndarray, dt: float, free: np.ndarray | None = None,
                       covariance: np.ndarray | None = None, n_points: int = 40) -> dict[str, Any] | None:
    """result.json's ``dispersion``: frequency_Hz, phase_velocity_m_s, attenuation_dB_per_cm and
    their standard errors (when a covariance of the free model parameters is given); None for
    models without a complex modulus or records without a band."""
    if not callable(getattr(model, "complex_modulus", None)):
        return None
    band = input_band(u, dt)
    if band is None:
        return None
    theta = np.asarray(theta, dtype=float)
    f = np.linspace(band[0], band[1], n_points)
    with np.errstate(all="ignore"):
        base = _curves(model, theta, f)
        if not np.all(np.isfinite(base)):
            return None
        out: dict[str, Any] = {
            "frequency_Hz": f.tolist(),
            "phase_velocity_m_s": base[:n_points].tolist(),
            "attenuation_dB_per_cm": base[n_points:].tolist(),
            "band_dB": BAND_DB,
            "wave": "longitudinal plane wave in the continuum of the normal properties",
        }
        if covariance is not None and free is not None and np.any(free):
            idx = np.flatnonzero(free)
            J = np.empty((base.size, idx.size))
            for j, i in enumerate(idx):
                h = 1e-6 * (abs(theta[i]) or 1.0)
                up, dn = theta.copy(), theta.copy()
                up[i] += h
                dn[i] -= h
                J[:, j] = (_curves(model, up, f) - _curves(model, dn, f)) / (2 * h)
            se = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", J, covariance, J), 0.0, None))
            if np.all(np.isfinite(se)):
                out["phase_velocity_se_m_s"] = se[:n_points].tolist()
                out["attenuation_se_dB_per_cm"] = se[n_points:].tolist()
    return out


def summary_line(section: dict[str, Any]) -> str:
    """'dispersion at 1.23 MHz (band centre): phase velocity ... m/s, attenuation ... dB/cm'."""
    i = len(section["frequency_Hz"]) // 2
    c, a = section["phase_velocity_m_s"][i], section["attenuation_dB_per_cm"][i]
    cse = section.get("phase_velocity_se_m_s")
    ase = section.get("attenuation_se_dB_per_cm")
    cs = f"{c:.5g}" + (f" +- {cse[i]:.2g}" if cse else "")
    as_ = f"{a:.4g}" + (f" +- {ase[i]:.2g}" if ase else "")
    return (f"  dispersion at {section['frequency_Hz'][i] / 1e6:.3g} MHz (band centre): phase velocity {cs} m/s, "
            f"attenuation {as_} dB/cm")
