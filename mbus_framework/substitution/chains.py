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
from functools import lru_cache

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
        return _chain_transmission(model, np.asarray(model.from_properties(to_props(p)), dtype=float), w, h, water)


CHAIN_LAWS = {
    "kelvin_voigt_chain": ChainLaw("kelvin_voigt_chain", LAWS["kelvin_voigt"], "kelvin_voigt"),
    "sls_chain": ChainLaw("sls_chain", LAWS["zener"], "sls"),
}

#: Bounds of a registered chain's normal properties by unit (log-fitted, like the laws').
_UNIT_BOUNDS = {"Pa": (1e3, 1e13), "Pa s": (1e-9, 1e6), "s": (1e-12, 1e3)}


@dataclass(frozen=True)
class ModelChainLaw:
    """Any registered chain model (``model:<name>``) in the substitution experiment: its own
    masses and normal links (shear off), parameters = its normal-direction properties (E_sigma,
    eta_sigma, E1_sigma, ...), transmission as :class:`ChainLaw`'s. The start moves the model's
    typical values along their time exponents until |M(w0)| matches the model-free modulus."""

    name: str
    model_name: str
    n_elements: int = DEFAULT_ELEMENTS

    def _model(self, rho: float = 1000.0, h: float = 1e-3):
        return _registered_chain(self.model_name, self.n_elements, float(rho), float(h))

    def _normal(self, model):
        names = [p.name for p in model.properties]
        units = {p.name: p.unit for p in model.properties}
        normal = [n for n in names if n.endswith("_sigma")]
        return normal, [units[n] for n in normal], names

    @property
    def parameters(self):
        return tuple(self._normal(self._model())[0])

    @property
    def units(self):
        return tuple(self._normal(self._model())[1])

    @property
    def bounds(self):
        return tuple(_UNIT_BOUNDS.get(u, (1e-6, 1e6)) for u in self.units)

    def _theta(self, model, p):
        normal, _, names = self._normal(model)
        typical = model.to_properties(np.array([q.typical for q in model.parameters]))
        props = {n: (float(v) if n not in normal else float(p[normal.index(n)])) for n, v in typical.items()}
        return np.asarray(model.from_properties(props), dtype=float)

    def modulus(self, w, p, w0):
        model = self._model()
        return np.asarray(model.complex_modulus(self._theta(model, p), np.asarray(w) / (2 * np.pi)), dtype=complex)

    def start(self, M, w0):
        """Typical values moved along their time exponents to the modulus level of ``M`` at w0,
        then the nearest point (least squares in log coordinates, from there) whose M(w0) equals
        the model-free modulus ``M`` in magnitude and phase."""
        from scipy.optimize import least_squares

        model = self._model()
        normal, units, _ = self._normal(model)
        typical = model.to_properties(np.array([q.typical for q in model.parameters]))
        base = np.array([typical[n] for n in normal])
        expo = np.array([{"Pa": 2.0, "Pa s": 1.0, "s": -1.0}.get(u, 0.0) for u in units])
        lo, hi = (np.log(np.array(b)) for b in zip(*self.bounds))

        def mismatch(x):
            Mx = complex(self.modulus(np.array([w0]), np.exp(x), w0)[0])
            d = np.log(Mx / M) if Mx != 0 and np.isfinite(Mx) else complex(1e3, 0.0)
            return np.array([d.real, d.imag])

        x0 = min((np.clip(np.log(base * c**expo), lo + 1e-6, hi - 1e-6) for c in np.geomspace(1e-4, 1e4, 81)),
                 key=lambda x: float(np.sum(mismatch(x) ** 2)))
        try:
            x0 = least_squares(mismatch, x0, bounds=(lo, hi), method="trf", max_nfev=200).x
        except (ValueError, np.linalg.LinAlgError):
            pass
        return np.exp(x0)

    def transmission(self, w: np.ndarray, p: np.ndarray, rho: float, h: float, water) -> np.ndarray:
        model = self._model(rho, h)
        return _chain_transmission(model, self._theta(model, p), w, h, water)


@lru_cache(maxsize=32)
def _registered_chain(model_name: str, n_elements: int, rho: float, h: float):
    """The registered chain plugin ``model_name`` on a unit-area column (built once per geometry:
    a fit evaluates it hundreds of times)."""
    from mbus_framework.engine.chain import ChainModel
    from mbus_framework.interfaces.registry import default_registry
    from mbus_framework.interfaces.sample import Sample

    cls = default_registry().get("model", model_name).implementation
    if not issubclass(cls, ChainModel) or "n_elements" not in cls.Options.model_fields:
        raise ValueError(f"model {model_name!r} is not a chain of masses and links; the substitution "
                         f"experiment fits chains (model:<chain>) and the laws")
    return cls(Sample(h, _UNIT_AREA_DIAMETER, rho), cls.Options(n_elements=n_elements))


def _chain_transmission(model, theta, w, h, water):
    """One-pass transmission of ``model``'s masses and normal links between two water half-spaces."""
    f = w / (2 * np.pi)
    K = np.asarray(model.complex_modulus(theta, f), dtype=complex) / model.geometry_factor("sigma")
    iw = 1j * w
    a, b, c, d = (np.ones_like(iw), np.zeros_like(iw), np.zeros_like(iw), np.ones_like(iw))
    masses = model.masses()
    for i, m in enumerate(masses):
        b, d = a * iw * m + b, c * iw * m + d  # mass: [[a, b], [c, d]] @ [[1, i w m], [0, 1]]
        if i < masses.size - 1:  # link: [[a, b], [c, d]] @ [[1, 0], [i w / K, 1]]
            a, c = a + b * iw / K, c + d * iw / K
    Zr = water.impedance * model.sample.area
    return 2 / (a + b / Zr + c * Zr + d) * np.exp(1j * w / water.speed * h)


MODEL_PREFIX = "model:"


def any_law(name: str):
    """A continuum law, a chain law, or ``model:<name>`` (any registered chain model, or a
    frequency-response model's law) by name; a one-line error listing the choices."""
    if name in CHAIN_LAWS:
        return CHAIN_LAWS[name]
    if name in LAWS:
        return LAWS[name]
    if name.startswith(MODEL_PREFIX):
        return registered_law(name[len(MODEL_PREFIX):])
    raise ValueError(f"unknown material law {name!r}; choose one of {', '.join(ALL_LAWS)} or model:<registered model>")


def registered_law(model_name: str):
    """The law of a registered model: a frequency-response model's continuum law, or a chain."""
    from mbus_framework.interfaces.registry import default_registry
    from mbus_framework.interfaces.sample import Sample

    reg = default_registry()
    if model_name not in reg.names("model"):
        raise ValueError(f"model:{model_name}: no such registered model ({', '.join(reg.names('model'))})")
    cls = reg.get("model", model_name).implementation
    if not getattr(cls, "has_state_space", True):
        law = getattr(cls(Sample(1e-3, 1.0, 1000.0), cls.Options()), "law", None)
        if law is None:
            raise ValueError(f"model:{model_name}: a frequency-response model without a continuum law")
        return law
    chain = ModelChainLaw(f"{MODEL_PREFIX}{model_name}", model_name)
    chain._model()  # one-line error now for a model that is not a chain
    return chain


ALL_LAWS = (*LAWS, *CHAIN_LAWS)
