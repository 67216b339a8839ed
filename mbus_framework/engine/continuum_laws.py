"""Material laws: the complex longitudinal modulus M(w) [Pa] of a viscoelastic solid (e^{iwt}).

A plane wave in the solid has wavenumber k = w sqrt(rho / M) = w / c - i alpha, phase velocity
c(w) = w / Re k [m/s], attenuation alpha(w) = -Im k [Np/m], impedance Z = rho w / k [Rayl].

Laws (parameters positive, fitted in log coordinates):

* ``kelvin_voigt``     M = E + i w eta                              (E [Pa], eta [Pa s]); alpha ~ f^2
* ``zener``            M = E_r + (E_u - E_r) i w tau / (1 + i w tau)  (E_r < E_u [Pa], tau [s])
* ``fractional_zener`` M = (E_r + E_u (i w tau)^a) / (1 + (i w tau)^a)  (E_r, E_u [Pa], tau [s],
                       0 < a <= 1; a = 1 is the Zener law; Bagley & Torvik 1983)
* ``constant_q``       M = M0 (i w / w0)^(2 gamma), gamma = arctan(1/Q) / pi  (Kjartansson 1979;
                       M0 [Pa], gamma [-], w0 = 2 pi f0 the reference frequency); alpha ~ f^1
* ``power_law``        M = E + eta_beta (i w)^beta                   (fractional Kelvin-Voigt: E [Pa],
                       eta_beta [Pa s^beta], 0 < beta < 1); alpha between f^1 and f^2

None of the fractional laws has a finite state space; each gives M and its exact parameter
derivatives dM/dp (:attr:`Law.jacobian`) at any w, which is all a frequency-response model needs.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class Law:
    """A named complex modulus M(w, p, w0) with its exact derivatives dM/dp (shape (n_p, n_w)),
    parameter names, units, time exponents (how each value moves when every time constant is
    divided by c: value * c**e, see :class:`~mbus_framework.interfaces.model.Parameter`), a start
    from one measured modulus M_ref at w0 (the band centre) and default bounds."""

    name: str
    parameters: tuple[str, ...]
    units: tuple[str, ...]
    modulus: Callable[[np.ndarray, np.ndarray, float], np.ndarray]
    start: Callable[[complex, float], np.ndarray]
    bounds: tuple[tuple[float, float], ...]
    jacobian: Callable[[np.ndarray, np.ndarray, float], np.ndarray] | None = None
    time_exponents: tuple[float, ...] = ()


def _log(z: np.ndarray) -> np.ndarray:
    """ln z with ln 0 -> 0 (the derivative terms it multiplies vanish there)."""
    z = np.asarray(z, dtype=complex)
    return np.log(np.where(z == 0, 1.0, z))


def _kv(w, p, w0):
    return p[0] + 1j * w * p[1]


def _kv_jac(w, p, w0):
    w = np.asarray(w, dtype=float)
    return np.array([np.ones_like(w, dtype=complex), 1j * w])


def _kv_start(M, w0):
    return np.array([M.real, max(M.imag, 1e-6 * M.real) / w0])


def _zener(w, p, w0):
    Er, Eu, tau = p
    return Er + (Eu - Er) * 1j * w * tau / (1 + 1j * w * tau)


def _zener_jac(w, p, w0):
    Er, Eu, tau = p
    s = 1j * np.asarray(w, dtype=float)
    g = s * tau / (1 + s * tau)
    return np.array([1 - g, g, (Eu - Er) * s / (1 + s * tau) ** 2])


def _zener_start(M, w0):
    d = max(2 * M.imag, 1e-3 * M.real)
    return np.array([max(M.real - d / 2, 0.1 * M.real), M.real + d / 2, 1 / w0])


def _fz(w, p, w0):
    Er, Eu, tau, a = p
    x = (1j * np.asarray(w, dtype=float) * tau) ** a
    return (Er + Eu * x) / (1 + x)


def _fz_jac(w, p, w0):
    Er, Eu, tau, a = p
    iwt = 1j * np.asarray(w, dtype=float) * tau
    x = iwt**a
    dM_dx = (Eu - Er) / (1 + x) ** 2
    return np.array([1 / (1 + x), x / (1 + x), dM_dx * a * x / tau, dM_dx * x * _log(iwt)])


def _fz_start(M, w0):
    return np.append(_zener_start(M, w0), 0.5)


def _constant_q(w, p, w0):
    return p[0] * (1j * np.asarray(w, dtype=float) / w0) ** (2 * p[1])


def _constant_q_jac(w, p, w0):
    M = _constant_q(w, p, w0)
    return np.array([M / p[0], 2 * M * _log(1j * np.asarray(w, dtype=float) / w0)])


def _constant_q_start(M, w0):
    return np.array([abs(M), min(max(np.angle(M) / np.pi, 1e-4), 0.49)])


def _power(w, p, w0):
    return p[0] + p[1] * (1j * np.asarray(w, dtype=float)) ** p[2]


def _power_jac(w, p, w0):
    s = 1j * np.asarray(w, dtype=float)
    sb = s ** p[2]
    return np.array([np.ones_like(sb), sb, p[1] * sb * _log(s)])


def _power_start(M, w0):
    beta = 0.5
    eta = max(M.imag, 1e-6 * M.real) / (w0**beta * np.sin(beta * np.pi / 2))
    return np.array([max(M.real - eta * w0**beta * np.cos(beta * np.pi / 2), 0.1 * M.real), eta, beta])


LAWS: dict[str, Law] = {
    law.name: law
    for law in (
        Law("kelvin_voigt", ("E", "eta"), ("Pa", "Pa s"), _kv, _kv_start, ((1e3, 1e13), (1e-9, 1e6)),
            _kv_jac, (2.0, 1.0)),
        Law(
            "zener", ("E_r", "E_u", "tau"), ("Pa", "Pa", "s"), _zener, _zener_start,
            ((1e3, 1e13), (1e3, 1e13), (1e-12, 1e3)), _zener_jac, (2.0, 2.0, -1.0),
        ),
        Law(
            "fractional_zener", ("E_r", "E_u", "tau", "alpha"), ("Pa", "Pa", "s", "-"), _fz, _fz_start,
            ((1e3, 1e13), (1e3, 1e13), (1e-12, 1e3), (1e-3, 1.0)), _fz_jac, (2.0, 2.0, -1.0, 0.0),
        ),
        Law("constant_q", ("M0", "gamma"), ("Pa", "-"), _constant_q, _constant_q_start,
            ((1e3, 1e13), (1e-6, 0.5)), _constant_q_jac, (2.0, 0.0)),
        Law(
            "power_law", ("E", "eta_beta", "beta"), ("Pa", "Pa s^beta", "-"), _power, _power_start,
            ((1e3, 1e13), (1e-9, 1e12), (1e-3, 0.999)), _power_jac, (2.0, 1.5, 0.0),
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
