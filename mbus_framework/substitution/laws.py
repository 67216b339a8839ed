"""Material laws: the complex longitudinal modulus M(w) [Pa] of a viscoelastic solid (e^{iwt}).

A plane wave in the solid has wavenumber k = w sqrt(rho / M) = w / c - i alpha, phase velocity
c(w) = w / Re k [m/s], attenuation alpha(w) = -Im k [Np/m], impedance Z = rho w / k [Rayl].

Laws (parameters positive, fitted in log coordinates):

* ``kelvin_voigt``  M = E + i w eta                              (E [Pa], eta [Pa s]); alpha ~ f^2
* ``zener``         M = E_r + (E_u - E_r) i w tau / (1 + i w tau)  (E_r < E_u [Pa], tau [s])
* ``constant_q``    M = M0 (i w / w0)^(2 gamma), gamma = arctan(1/Q) / pi  (Kjartansson 1979;
                    M0 [Pa], gamma [-], w0 = 2 pi f0 the reference frequency); alpha ~ f^1
* ``power_law``     M = E + eta_beta (i w)^beta                   (fractional Kelvin-Voigt: E [Pa],
                    eta_beta [Pa s^beta], 0 < beta < 1); alpha ~ f^(1+beta)/.. between the two
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class Law:
    """A named complex modulus M(w, p, w0) with parameter names, units and a start from one
    measured modulus M_ref at w0 (the band centre)."""

    name: str
    parameters: tuple[str, ...]
    units: tuple[str, ...]
    modulus: Callable[[np.ndarray, np.ndarray, float], np.ndarray]
    start: Callable[[complex, float], np.ndarray]
    bounds: tuple[tuple[float, float], ...]


def _kv(w, p, w0):
    return p[0] + 1j * w * p[1]


def _kv_start(M, w0):
    return np.array([M.real, max(M.imag, 1e-6 * M.real) / w0])


def _zener(w, p, w0):
    Er, Eu, tau = p
    return Er + (Eu - Er) * 1j * w * tau / (1 + 1j * w * tau)


def _zener_start(M, w0):
    d = max(2 * M.imag, 1e-3 * M.real)
    return np.array([max(M.real - d / 2, 0.1 * M.real), M.real + d / 2, 1 / w0])


def _constant_q(w, p, w0):
    return p[0] * (1j * w / w0) ** (2 * p[1])


def _constant_q_start(M, w0):
    return np.array([abs(M), min(max(np.angle(M) / np.pi, 1e-4), 0.49)])


def _power(w, p, w0):
    return p[0] + p[1] * (1j * w) ** p[2]


def _power_start(M, w0):
    beta = 0.5
    eta = max(M.imag, 1e-6 * M.real) / (w0**beta * np.sin(beta * np.pi / 2))
    return np.array([max(M.real - eta * w0**beta * np.cos(beta * np.pi / 2), 0.1 * M.real), eta, beta])


LAWS: dict[str, Law] = {
    law.name: law
    for law in (
        Law("kelvin_voigt", ("E", "eta"), ("Pa", "Pa s"), _kv, _kv_start, ((1e5, 1e13), (1e-9, 1e6))),
        Law(
            "zener", ("E_r", "E_u", "tau"), ("Pa", "Pa", "s"), _zener, _zener_start,
            ((1e5, 1e13), (1e5, 1e13), (1e-12, 1e-3)),
        ),
        Law("constant_q", ("M0", "gamma"), ("Pa", "-"), _constant_q, _constant_q_start, ((1e5, 1e13), (1e-6, 0.5))),
        Law(
            "power_law", ("E", "eta_beta", "beta"), ("Pa", "Pa s^beta", "-"), _power, _power_start,
            ((1e5, 1e13), (1e-9, 1e12), (1e-3, 0.999)),
        ),
    )
}


def law_named(name: str) -> Law:
    """The law called ``name``; a one-line error listing the others."""
    try:
        return LAWS[name]
    except KeyError:
        raise ValueError(f"unknown material law {name!r}; choose one of {', '.join(LAWS)}") from None


def wavenumber(M: np.ndarray, w: np.ndarray, rho: float) -> np.ndarray:
    """k = w sqrt(rho / M) on the branch with Re k > 0, Im k <= 0 (a decaying forward wave)."""
    k = w * np.sqrt(rho / np.asarray(M, dtype=complex))
    return np.where(k.real < 0, -k, k)


def velocity_attenuation(k: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Phase velocity c = w / Re k [m/s] and attenuation alpha = -Im k [Np/m]."""
    return w / k.real, -k.imag
