"""Lumped chains in the substitution experiment: the plate as mbus's chain of masses and normal
links (no shear: nothing holds an immersed plate sideways) between two water half-spaces.

Per element, force F and velocity v obey [F, v]_in = P [F, v]_out with
P = [[1, i w m], [0, 1]] for a mass m [kg] and [[1, 0], [i w / K, 1]] for a link of dynamic
stiffness K(w) [N/m]; for the chain's product [[a, b], [c, d]] between media of mechanical
impedance Zr = rho0 c0 A, one pass transmits T = 2 / (a + b / Zr + c Zr + d) e^{i k0 h}
(the transfer-matrix formula of a layer, which the continuum's matrix reproduces as n -> inf).
The chain is the model plugin's own (masses, geometry factor, link law), so the fitted
properties are those a contact-method run of the same model reports.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mbus_framework.engine.continuum_laws import LAWS, Law

#: Elements of the chain by default (the most a chain model accepts): cut-off n c / (pi L) far above
#: the band of mm plates; the chain spans (n - 1) L / n, so its properties carry an O(1/n) bias.
DEFAULT_ELEMENTS = 100
_UNIT_AREA_DIAMETER = float(np.sqrt(4 / np.pi))  # A = 1 m^2: properties do not depend on it


def _kv_properties(p):
    return {"E_sigma": p[0], "eta_sigma": p[1], "E_tau": 1.0, "eta_tau": 1.0}


def _sls_properties(p):  # Zener (E_r, E_u, tau): parallel spring E_r, Maxwell arm E_u - E_r with tau
    e1 = max(p[1] - p[0], 1e-9 * p[1])
    return {"E_sigma": p[0], "E1_sigma": e1, "eta1_sigma": e1 * p[2], "E_tau": 1.0, "E1_tau": 1.0, "eta1_tau": 1.0}


@dataclass(frozen=True)
class ChainLaw:
    """A chain model fitted through the continuum law its normal link law is (same
    parameters, start and bounds); ``transmission`` replaces the continuum plate."""

    name: str
    continuum: Law
    model_name: str
    n_elements: int = DEFAULT_ELEMENTS

    @property
    def parameters(self):
        return self.continuum.parameters

    @property
    def units(self):
        return self.continuum.units

    @property
    def bounds(self):
        return self.continuum.bounds

    def start(self, M, w0):
        return self.continuum.start(M, w0)

    def modulus(self, w, p, w0):
        return self.continuum.modulus(w, p, w0)

    def _model(self, rho: float, h: float):
        from mbus_framework.interfaces.sample import Sample

        if self.model_name == "kelvin_voigt":
            from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

            return KelvinVoigtChain(Sample(h, _UNIT_AREA_DIAMETER, rho), KelvinVoigtOptions(n_elements=self.n_elements)), _kv_properties
        from mbus_plugins.models.sls import SlsChain, SlsOptions

        return SlsChain(Sample(h, _UNIT_AREA_DIAMETER, rho), SlsOptions(n_elements=self.n_elements)), _sls_properties

    def transmission(self, w: np.ndarray, p: np.ndarray, rho: float, h: float, water) -> np.ndarray:
        """One-pass transmission of the chain relative to water (module docstring)."""
        model, to_props = self._model(rho, h)
        theta = np.asarray(model.from_properties(to_props(p)), dtype=float)
        f = w / (2 * np.pi)
        K = np.asarray(model.complex_modulus(theta, f), dtype=complex) / model.geometry_factor("sigma")
        iw = 1j * w
        a, b, c, d = (np.ones_like(iw), np.zeros_like(iw), np.zeros_like(iw), np.ones_like(iw))
        masses = model.masses()
        for i, m in enumerate(masses):
            # mass: [[a, b], [c, d]] @ [[1, i w m], [0, 1]]
            b, d = a * iw * m + b, c * iw * m + d
            if i < masses.size - 1:  # link: [[a, b], [c, d]] @ [[1, 0], [i w / K, 1]]
                a, c = a + b * iw / K, c + d * iw / K
        Zr = water.impedance * model.sample.area
        return 2 / (a + b / Zr + c * Zr + d) * np.exp(1j * w / water.speed * h)


CHAIN_LAWS = {
    "kelvin_voigt_chain": ChainLaw("kelvin_voigt_chain", LAWS["kelvin_voigt"], "kelvin_voigt"),
    "sls_chain": ChainLaw("sls_chain", LAWS["zener"], "sls"),
}


def any_law(name: str):
    """A continuum law or a chain law by name; a one-line error listing both."""
    if name in CHAIN_LAWS:
        return CHAIN_LAWS[name]
    if name in LAWS:
        return LAWS[name]
    raise ValueError(f"unknown material law {name!r}; choose one of {', '.join(ALL_LAWS)}")


ALL_LAWS = (*LAWS, *CHAIN_LAWS)
