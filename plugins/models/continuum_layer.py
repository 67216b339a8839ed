"""The exact continuum viscoelastic layer: plane waves in the column, all reverberations.

The sample column (length L [m], density rho [kg/m^3]) is a continuum with the complex
longitudinal modulus M(w) of a material law (:mod:`mbus_framework.engine.continuum_laws`:
Kelvin-Voigt, Zener, fractional Zener, constant Q, power law). With the force u on the free
transmitter face (x = 0) and the receiver a rigid wall (x = L), the displacement is
w(x) ~ sin k (L - x), k = w sqrt(rho / M), and the normal force F = -A M dw/dx gives

    H(s) = F(L) / F(0) = 1 / cos(k L),         s = i w,

independent of the cross-section: the limit of the lumped chains (same boundary conditions)
as the number of masses grows, without lateral shear (a plane wave loses nothing sideways).
Its poles k L = (j + 1/2) pi are the column's quarter-wave resonances; every internal
reverberation is included. No finite state space exists for the fractional laws (nor for the
continuum at all), so this is a :class:`~mbus_framework.interfaces.model.FrequencyResponseModel`:
records are simulated by exact convolution and dH/dp = L sin(kL) / cos^2(kL) dk/dM dM/dp,
dk/dM = -k / (2 M), with the law's exact dM/dp.

Parameters are the law's material coefficients themselves (E [Pa], eta [Pa s], tau [s], ...),
so the properties equal the parameters. ``fractional_zener`` is this layer with the fractional
Zener law (Bagley & Torvik 1983): M = (E_r + E_u (i w tau)^alpha) / (1 + (i w tau)^alpha).
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.engine.continuum_laws import LAWS, Law
from mbus_framework.engine.physics import first_arrival_time
from mbus_framework.interfaces.hookspecs import MediumModelSpec, hookimpl
from mbus_framework.interfaces.model import FrequencyResponseModel, Parameter, Property

LawName = Literal["kelvin_voigt", "zener", "fractional_zener", "constant_q", "power_law"]

_DESCRIPTIONS = {
    "E": "elastic modulus", "eta": "viscosity", "E_r": "relaxed modulus", "E_u": "unrelaxed modulus",
    "tau": "relaxation time", "alpha": "fractional order", "M0": "modulus magnitude at f0",
    "gamma": "loss exponent, arctan(1/Q)/pi", "eta_beta": "fractional viscosity", "beta": "fractional order",
}


class ContinuumLayerOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    law: LawName = Field("fractional_zener", description="material law M(w) of the layer")
    reference_frequency_Hz: float = Field(1.0e5, gt=0, description="f0 of the constant_q law [Hz]")


class ContinuumLayer(FrequencyResponseModel):
    """Exact plane-wave column with a continuum material law (module docstring)."""

    Options = ContinuumLayerOptions
    summary = "exact continuum layer, any material law (frequency response only)"

    @property
    def law(self) -> Law:
        return LAWS[self.options.law]

    @property
    def w0(self) -> float:
        return 2 * np.pi * self.options.reference_frequency_Hz

    @property
    def parameters(self):
        law = self.law
        typical = law.start(complex(2.0e6, 2.0e5), self.w0)
        return tuple(
            Parameter(name, unit, _DESCRIPTIONS.get(name, name), lo, hi, float(t), e)
            for name, unit, (lo, hi), t, e in zip(law.parameters, law.units, law.bounds, typical, law.time_exponents)
        )

    @property
    def properties(self):
        return tuple(Property(p.name, p.unit, p.description) for p in self.parameters)

    def to_properties(self, theta) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.law.parameters, np.asarray(theta, dtype=float))}

    def from_properties(self, properties) -> np.ndarray:
        return np.array([float(properties[n]) for n in self.law.parameters])

    def complex_modulus(self, theta, f) -> np.ndarray:
        """M(w) [Pa] at frequencies ``f`` [Hz]."""
        w = 2 * np.pi * np.asarray(f, dtype=float)
        return np.asarray(self.law.modulus(w, np.asarray(theta, dtype=float), self.w0), dtype=complex)

    def _wavenumber(self, theta, s):
        w = np.asarray(s, dtype=complex).imag
        M = np.asarray(self.law.modulus(w, np.asarray(theta, dtype=float), self.w0), dtype=complex)
        M = np.broadcast_to(M, w.shape)
        with np.errstate(all="ignore"):
            k = w * np.sqrt(self.sample.density / M)
        k = np.where(w == 0, 0.0, k)  # the static limit (M(0) may be 0, as for constant Q): H(0) = 1
        return w, M, np.where(k.real < 0, -k, k)

    def _response_and_tangent(self, k):
        """1 / cos(kL) and tan(kL) through q = e^{-2ikL} (|q| <= 1 on the decaying branch, so no
        overflow however lossy): 1/cos = 2 e^{-ikL} / (1 + q), tan = -i (1 - q) / (1 + q)."""
        x = k * self.sample.length
        q = np.exp(-2j * x)
        return 2 * np.exp(-1j * x) / (1 + q), -1j * (1 - q) / (1 + q)

    def frequency_response(self, theta, s) -> np.ndarray:
        _, _, k = self._wavenumber(theta, s)
        with np.errstate(all="ignore"):
            return self._response_and_tangent(k)[0]

    def frequency_response_jacobian(self, theta, s):
        theta = np.asarray(theta, dtype=float)
        w, M, k = self._wavenumber(theta, s)
        with np.errstate(all="ignore"):
            H, tangent = self._response_and_tangent(k)
            dH_dM = self.sample.length * tangent * H * (-k / (2 * M))  # d(1/cos x)/dx = tan x / cos x
        dH_dM = np.where(w == 0, 0.0, dH_dM)
        dM = np.broadcast_to(np.asarray(self.law.jacobian(w, theta, self.w0), dtype=complex), (theta.size, w.size))
        return H, dH_dM[None, :] * dM

    def initial_guess(self, t, u, y) -> np.ndarray:
        """The law's start at M = rho v^2 (1 + i d), v = L / first-arrival time (Section 3.5.1's
        sound-speed idea), at the centroid w_c of the input's power spectrum; the loss d is the
        one of 0.01-0.5 (log-spaced) whose simulated record is closest to ``y`` (one FFT
        convolution each)."""
        from mbus_framework.engine.convolution import simulate_response

        t, u, y = (np.asarray(a, dtype=float) for a in (t, u, y))
        t_arr = first_arrival_time(t, u, y)
        if t_arr is None or t_arr <= 0:
            return np.array([p.typical for p in self.parameters])
        dt = float(t[1] - t[0])
        P = np.abs(np.fft.rfft(u - u.mean())) ** 2
        f = np.fft.rfftfreq(u.size, dt)
        wc = 2 * np.pi * float(np.sum(f * P) / np.sum(P)) if np.sum(P) > 0 else self.w0
        lo, hi = (np.array(b) for b in zip(*self.law.bounds))
        level = self.sample.density * (self.sample.length / t_arr) ** 2
        best, best_cost = None, np.inf
        for d in np.geomspace(0.01, 0.5, 8):
            theta = np.clip(self.law.start(complex(level, level * d), wc), lo, hi)
            with np.errstate(all="ignore"):
                r = y - simulate_response(self, theta, u, dt)
            cost = float(r @ r)
            if np.isfinite(cost) and cost < best_cost:
                best, best_cost = theta, cost
        return best if best is not None else np.array([p.typical for p in self.parameters])


class FractionalZenerOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")


class FractionalZener(ContinuumLayer):
    """Continuum layer with the fractional Zener law: E_r, E_u [Pa], tau [s], alpha [-]."""

    Options = FractionalZenerOptions
    summary = "fractional Zener (springpot) continuum layer: E_r, E_u, tau, alpha (frequency response only)"

    @property
    def law(self) -> Law:
        return LAWS["fractional_zener"]

    @property
    def w0(self) -> float:
        return 2 * np.pi * 1.0e5


@hookimpl
def mbus_medium_models():
    return [
        MediumModelSpec("continuum_layer", ContinuumLayer, ContinuumLayer.summary),
        MediumModelSpec("fractional_zener", FractionalZener, FractionalZener.summary),
    ]
