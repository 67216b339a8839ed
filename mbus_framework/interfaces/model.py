"""Medium-model interface: a lumped viscoelastic sample as a linear state-space model.

A model maps a parameter vector theta (SI units) to continuous-time matrices

    dz/dt = A(theta) z + B(theta) u,      y = C(theta) z + D(theta) u

with u the force on the transmitter side [N] and y the force on the receiver [N].
Implementations subclass :class:`MediumModel`, write :meth:`MediumModel.state_space`
with arithmetic only (see :mod:`mbus_framework.engine.arrays`) and register through the
``mbus_medium_models`` hook.

Laws with no finite state space (fractional derivatives, power-law attenuation, the exact
continuum) subclass :class:`FrequencyResponseModel` instead and give only
H(s; theta) = Y(s)/U(s) and its exact derivatives; the engine then simulates a record by exact
(zero-padded FFT) convolution (:mod:`mbus_framework.engine.convolution`).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar, Mapping, NamedTuple, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict

from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.sample import Sample


class NoOptions(BaseModel):
    """Options model for plugins that take no options."""

    model_config = ConfigDict(extra="forbid")


class StateSpace(NamedTuple):
    """Continuous-time state-space matrices (A: nxn, B: nx1, C: 1xn, D: 1x1)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray


@dataclass(frozen=True)
class Parameter:
    """One estimated model coefficient.

    ``lower``/``upper`` are the default bounds; ``typical`` is a scale used when nothing
    better is known. ``time_exponent`` e says how the value moves when every time constant
    of the model is divided by c (the dynamics run c times faster, masses fixed): the value
    becomes value * c**e. Stiffness [N/m]: 2, damping [N s/m]: 1, relaxation time [s]: -1,
    dimensionless: 0. Estimators use it to align the model's wave arrival with the data
    before any local fit (the first-arrival -> sound-speed idea of Section 3.5.1, generalised).
    ``log_scale``: estimate ln(value) (positive parameters spanning decades); False for
    parameters that may be zero, such as a delay.
    """

    name: str
    unit: str
    description: str
    lower: float = 0.0
    upper: float = np.inf
    typical: float = 1.0
    time_exponent: float = 0.0
    log_scale: bool = True


@dataclass(frozen=True)
class Property:
    """One derived material property, e.g. an elastic modulus [Pa].

    ``positive``: the property cannot be zero or negative (a modulus, a viscosity, a time); its
    95 % interval is then computed on the log scale, v exp(-+q SE/v), and never contains zero.
    """

    name: str
    unit: str
    description: str
    positive: bool = True


@dataclass
class MediumModel(ABC):
    """Base class of medium models. Subclasses set the class attributes and the methods.

    Subclasses receive the sample geometry and their validated options (an instance of
    their ``Options`` pydantic model).
    """

    sample: Sample
    options: BaseModel = field(default_factory=NoOptions)

    Options: ClassVar[type[BaseModel]] = NoOptions
    summary: ClassVar[str] = ""
    has_state_space: ClassVar[bool] = True

    # -- what the model is -------------------------------------------------------------
    @property
    @abstractmethod
    def parameters(self) -> Sequence[Parameter]:
        """The estimated coefficients, in the order of theta."""

    @property
    @abstractmethod
    def properties(self) -> Sequence[Property]:
        """The material properties :meth:`to_properties` returns, in order."""

    @abstractmethod
    def state_space(self, theta) -> StateSpace:
        """Matrices at ``theta`` (float, complex or CasADi object array; arithmetic only)."""

    @abstractmethod
    def to_properties(self, theta) -> dict[str, float]:
        """Material properties from model parameters (SI units)."""

    @abstractmethod
    def from_properties(self, properties: Mapping[str, float]) -> np.ndarray:
        """Inverse of :meth:`to_properties`: parameters from material properties."""

    # -- optional hooks with generic defaults -------------------------------------------
    def initial_guess(self, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Physics-based starting values from the measured record. Default: ``typical``."""
        return np.array([p.typical for p in self.parameters], dtype=float)

    # -- conveniences -------------------------------------------------------------------
    @property
    def parameter_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def property_names(self) -> list[str]:
        return [p.name for p in self.properties]

    @property
    def n_states(self) -> int:
        return int(self.state_space(np.array([p.typical for p in self.parameters])).A.shape[0])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.array([p.lower for p in self.parameters], dtype=float)
        hi = np.array([p.upper for p in self.parameters], dtype=float)
        return lo, hi

    def theta_from_mapping(self, values: Mapping[str, float], where: str) -> np.ndarray:
        """Parameter vector from a mapping of parameter names *or* property names.

        ``where`` names the config key for error messages.
        """
        keys = set(values)
        pnames, prnames = set(self.parameter_names), set(self.property_names)
        if keys == pnames:
            return np.array([float(values[n]) for n in self.parameter_names])
        if keys == prnames:
            return np.asarray(self.from_properties({k: float(v) for k, v in values.items()}), float)
        from mbus_framework.suggest import did_you_mean

        unknown = sorted(keys - pnames - prnames)
        if unknown:
            hint = did_you_mean(unknown[0], self.parameter_names + self.property_names)
            raise ConfigError(f"{where}.{unknown[0]}: not a parameter or property of this model{hint}")
        missing = sorted((pnames - keys) if keys & pnames else (prnames - keys))
        raise ConfigError(
            f"{where}: give all of {', '.join(self.parameter_names)} or all of "
            f"{', '.join(self.property_names)}; missing {', '.join(missing)}"
        )


class FrequencyResponseModel(MediumModel):
    """A medium defined by its transfer function only: y(s) = H(s; theta) u(s), s = i w.

    Subclasses write :meth:`frequency_response` and :meth:`frequency_response_jacobian`
    (exact derivatives) besides the parameters and properties. The model must be causal with an
    impulse response that has decayed within the record's length: a record of N samples is
    simulated by convolution on a zero-padded FFT grid of at least 2N points, exact for such a
    response (:mod:`mbus_framework.engine.convolution`). No collocation solver (it needs states).
    """

    has_state_space: ClassVar[bool] = False

    @abstractmethod
    def frequency_response(self, theta, s: np.ndarray) -> np.ndarray:
        """H(s) (complex, shape of ``s``) at s = i w [rad/s]."""

    @abstractmethod
    def frequency_response_jacobian(self, theta, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H(s), dH/dtheta with shape (len(theta), len(s))), exact."""

    def state_space(self, theta) -> StateSpace:
        from mbus_framework.errors import PluginError

        raise PluginError("this model is defined by its frequency response only: it has no state space "
                          "(use the scipy_lm or frequency_domain solver)")

    @property
    def n_states(self) -> int:
        return 0
