"""Layered sample: a chain through several layers, each with its own length, density and links.

The column (diameter D) is a stack of layers l = 1..m (transmitter side first), e.g. skin and
flesh, or coupling plates around a sample (dissertation Section 8.2, heterogeneous media).
Layer l has length L_l, density rho_l, n_l elements of length L_l/n_l and element mass
mu_l = rho_l (pi D^2/4) L_l / n_l, and its own normal and shear link laws
(:mod:`mbus_framework.engine.chain`). Elements are numbered through the stack, i = 1..N (N = sum n_l).
Node i sits at the transmitter-side end of element i:

    normal link i (law and coefficients of element i's layer) joins node i and node i+1;
    the last one joins node N and the receiver; shear link i ties node i to the surroundings;
    masses (eq. 3.13 generalised): m_1 = mu_1/2, m_N = mu_N/2, m_i = (mu_{i-1} + mu_i)/2.

With one layer this is the plain chain of the same law (tested to round-off).

Parameters are the layer laws' coefficients named ``<symbol>_<direction>_<layer>``
(e.g. ``k_sigma_skin`` [N/m], ``b_tau_flesh`` [N s/m]) with the laws' units, time exponents
(stiffness 2, damping 1) and bounds (0, inf). Per layer, ``fixed`` holds coefficients at
known values (given as a coefficient, ``k_sigma: 1.2e9``, or as a material property,
``E_sigma: 5.6e9`` for an acrylic plate); fixed coefficients are not parameters at all.
``shared`` names coefficients that all layers (where not fixed) take from one parameter,
named without the layer suffix: the layers share the *material property* (eqs. 3.32-3.38):
E = (L_l/n_l)/(pi D^2/4) k_l is the same in every layer, so the parameter is the first
sharing layer's coefficient and layer l uses k_first (L_first/n_first)/(L_l/n_l).

Properties: per layer (and per shared parameter) as the plain chain, E_sigma = (L_l/n_l)/
(pi D^2/4) k_sigma, eta_sigma = (L_l/n_l)/(pi D^2/4) b_sigma, E_tau = k_tau/(pi D),
eta_tau = b_tau/(pi D), named like the parameters (``E_sigma_skin``, shared ``E_tau``).

Initial values: each layer's typical values, then every free parameter is moved along its
time exponent until the travel time sum_l L_l / v_l (v_l the layer's unrelaxed chain wave
speed) equals the first-arrival time (Section 3.5.1).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from mbus_framework.engine.chain import (
    ChainModel,
    ChainOptions,
    LinkLaw,
    assemble_chain,
    driving_point_velocity_row,
    link_law,
)
from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.hookspecs import MediumModelSpec, hookimpl
from mbus_plugins.models.bounds import Elements, check_elements
from mbus_framework.interfaces.model import MediumModel, Parameter, Property, StateSpace
from mbus_framework.engine.physics import first_arrival_time
from mbus_framework.interfaces.sample import Sample
from mbus_framework.suggest import did_you_mean

LawName = Literal["kelvin_voigt", "maxwell", "sls", "generalized_maxwell"]


class LayerOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str | None = Field(None, description="layer name used in parameter names (default layer<i>)")
    length: float | None = Field(None, gt=0, description="thickness L_l [m]; one layer may omit it (the rest)")
    density: float | None = Field(None, gt=0, description="density rho_l [kg/m^3] (default: sample density)")
    n_elements: Elements = Field(5, description="elements n_l in this layer")
    link: LawName | None = Field(None, description="normal link law (default: the model's `link`)")
    shear_link: LawName | Literal["same", "none"] | None = Field(None, description="shear link law (default: the model's)")
    fixed: dict[str, float] = Field(default_factory=dict, description="coefficients or properties held fixed")

    @field_validator("name")
    @classmethod
    def _identifier(cls, v):
        if v is not None and not v.isidentifier():
            raise ValueError(f"layer name {v!r} must be an identifier (letters, digits, _)")
        return v


class LayeredOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    layers: list[LayerOptions] = Field(min_length=1, description="layers from transmitter to receiver")
    link: LawName = Field("kelvin_voigt", description="normal link law of every layer")
    shear_link: LawName | Literal["same", "none"] = Field("same", description="shear link law ('same' = link)")
    n_arms: int = Field(2, ge=1, le=8, description="arms of generalized_maxwell links")
    shared: list[str] = Field(default_factory=list, description="coefficients shared by all layers, e.g. [k_tau, b_tau]")

    @model_validator(mode="after")
    def _names(self):
        names = [layer.name or f"layer{i + 1}" for i, layer in enumerate(self.layers)]
        if len(set(names)) != len(names):
            raise ValueError(f"layer names must be unique, got {names}")
        if sum(layer.length is None for layer in self.layers) > 1:
            raise ValueError("at most one layer may omit its length (it takes the rest of sample.length)")
        check_elements(sum(layer.n_elements for layer in self.layers), "elements in all layers together")
        return self


class LayerChain(ChainModel):
    """One layer as a uniform chain (used for its parameters, properties and conversions)."""

    def __init__(self, sample: Sample, n_elements: int, normal: LinkLaw, shear: LinkLaw | None, name: str):
        super().__init__(sample, ChainOptions(n_elements=n_elements))
        self._normal, self._shear, self.name = normal, shear, name

    def normal_law(self):
        return self._normal

    def shear_law(self):
        return self._shear


@dataclass
class LayeredChain(MediumModel):
    """A chain through a stack of layers with their own geometry, density and link laws."""

    Options = LayeredOptions
    summary = "layered sample: per-layer length, density and link laws; shared/fixed coefficients"

    def __post_init__(self):
        o = self.options
        where = "model.options.layers"
        given = sum(layer.length for layer in o.layers if layer.length is not None)
        lengths = []
        for layer in o.layers:
            if layer.length is None:
                rest = self.sample.length - given
                if rest <= 0:
                    raise ConfigError(f"{where}: the given layer lengths ({given:g} m) leave nothing of "
                                      f"sample.length ({self.sample.length:g} m) for the layer without a length")
                lengths.append(rest if len(o.layers) > 1 else self.sample.length)
            else:
                lengths.append(layer.length)
        if all(layer.length is not None for layer in o.layers) and not np.isclose(
            sum(lengths), self.sample.length, rtol=1e-6, atol=0.0
        ):
            raise ConfigError(f"{where}: layer lengths add up to {sum(lengths):g} m but sample.length is "
                              f"{self.sample.length:g} m")
        self.layers: list[LayerChain] = []
        for i, (layer, length) in enumerate(zip(o.layers, lengths)):
            normal = link_law(layer.link or o.link, o.n_arms)
            shear_name = layer.shear_link or o.shear_link
            shear = None if shear_name == "none" else normal if shear_name == "same" else link_law(shear_name, o.n_arms)
            density = layer.density if layer.density is not None else self.sample.density
            lsample = Sample(length, self.sample.diameter, density)
            self.layers.append(LayerChain(lsample, layer.n_elements, normal, shear, layer.name or f"layer{i + 1}"))
        self._build_map()

    # -- parameter bookkeeping -------------------------------------------------------------
    def _build_map(self) -> None:
        """self._sources[l][j] = ('free', theta index, scale) or ('fixed', value)."""
        o = self.options
        all_base = {p.name for layer in self.layers for p in layer.parameters}
        for name in o.shared:
            if name not in all_base:
                raise ConfigError(f"model.options.shared: '{name}' is not a coefficient of any layer"
                                  f"{did_you_mean(name, sorted(all_base))}; choose from {', '.join(sorted(all_base))}")
        params: list[Parameter] = []
        props: list[Property] = []
        shared_index: dict[str, tuple[int, LayerChain]] = {}
        self._sources: list[list[tuple]] = []
        for layer, lopt in zip(self.layers, o.layers):
            fixed = self._fixed_values(layer, lopt.fixed)
            sources = []
            for j, (p, prop) in enumerate(zip(layer.parameters, layer.properties)):
                if p.name in fixed:
                    sources.append(("fixed", fixed[p.name]))
                    continue
                if p.name in o.shared:
                    if p.name not in shared_index:
                        shared_index[p.name] = (len(params), layer)
                        params.append(Parameter(p.name, p.unit, f"{p.description} (shared by all layers)", p.lower,
                                                p.upper, p.typical, p.time_exponent))
                        props.append(Property(prop.name, prop.unit, f"{prop.description} (shared by all layers)"))
                        sources.append(("free", shared_index[p.name][0], 1.0))
                    else:
                        index, first = shared_index[p.name]
                        geometric = self._geometric(layer, j)
                        scale = (first.geometry_factor(_suffix(p.name)) / layer.geometry_factor(_suffix(p.name))
                                 if geometric else 1.0)
                        sources.append(("free", index, scale))
                    continue
                sources.append(("free", len(params), 1.0))
                params.append(Parameter(f"{p.name}_{layer.name}", p.unit, f"{p.description} in layer {layer.name}",
                                        p.lower, p.upper, p.typical, p.time_exponent))
                props.append(Property(f"{prop.name}_{layer.name}", prop.unit, f"{prop.description} in layer {layer.name}"))
            self._sources.append(sources)
        if not params:
            raise ConfigError("model.options: every coefficient is fixed; nothing left to estimate")
        self._parameters, self._properties = tuple(params), tuple(props)
        # which layer/coefficient defines each parameter's property
        self._owner: list[tuple[LayerChain, int]] = [None] * len(params)  # type: ignore[list-item]
        for layer, sources in zip(self.layers, self._sources):
            for j, src in enumerate(sources):
                if src[0] == "free" and self._owner[src[1]] is None:
                    self._owner[src[1]] = (layer, j)

    @staticmethod
    def _geometric(layer: LayerChain, j: int) -> bool:
        laws = [(d, lp) for d in layer.directions() for lp in d.law.parameters]
        return laws[j][1].geometric

    @staticmethod
    def _fixed_values(layer: LayerChain, fixed: Mapping[str, float]) -> dict[str, float]:
        """Fixed coefficients of a layer from coefficient or property names."""
        by_param = [p.name for p in layer.parameters]
        by_prop = [p.name for p in layer.properties]
        out = {}
        for key, value in fixed.items():
            if key in by_param:
                out[key] = float(value)
            elif key in by_prop:
                j = by_prop.index(key)
                geometric = LayeredChain._geometric(layer, j)
                suffix = _suffix(by_param[j])
                out[by_param[j]] = layer.property_to_coefficient(suffix, float(value)) if geometric else float(value)
            else:
                raise ConfigError(f"model.options.layers[{layer.name}].fixed.{key}: not a coefficient or property of "
                                  f"this layer{did_you_mean(key, by_param + by_prop)}; choose from "
                                  f"{', '.join(by_param + by_prop)}")
        return out

    def layer_values(self, theta) -> list[list]:
        """Every layer's coefficient values (shared scaled, fixed inserted); arithmetic only."""
        out = []
        for sources in self._sources:
            vals = []
            for src in sources:
                if src[0] == "fixed":
                    vals.append(src[1])
                else:
                    v = theta[src[1]]
                    vals.append(v if src[2] == 1.0 else v * src[2])
            out.append(vals)
        return out

    @property
    def exact_time_scaling(self) -> bool:
        """False when coefficients are fixed: they do not move with the time exponents, so
        scaling the parameters makes the dynamics only approximately c times faster."""
        return not any(src[0] == "fixed" for sources in self._sources for src in sources)

    # -- MediumModel interface -------------------------------------------------------------
    @property
    def parameters(self):
        return self._parameters

    @property
    def properties(self):
        return self._properties

    def masses(self) -> np.ndarray:
        """Node masses: mu_1/2, (mu_{i-1} + mu_i)/2 inside, mu_N/2 at the receiver end [kg]."""
        mu = np.concatenate([np.full(layer.n, layer.element_mass) for layer in self.layers])
        m = np.empty_like(mu)
        m[0] = mu[0] / 2.0
        m[1:] = (mu[:-1] + mu[1:]) / 2.0
        m[-1] = mu[-1] / 2.0
        return m

    def state_space(self, theta) -> StateSpace:
        normal_links, shear_links = [], []
        for layer, vals in zip(self.layers, self.layer_values(theta)):
            (dn, sn), *rest = layer._slices()
            lm_n = dn.law.matrices(vals[sn])
            lm_s = rest[0][0].law.matrices(vals[rest[0][1]]) if rest else None
            normal_links += [lm_n] * layer.n
            shear_links += [lm_s] * layer.n
        return assemble_chain(self.masses(), normal_links, shear_links, theta)

    def to_properties(self, theta) -> dict[str, float]:
        theta = np.asarray(theta, dtype=float)
        out = {}
        for i, (prop, (layer, j)) in enumerate(zip(self._properties, self._owner)):
            p = layer.parameters[j]
            v = float(theta[i])
            out[prop.name] = layer.coefficient_to_property(_suffix(p.name), v) if self._geometric(layer, j) else v
        return out

    def from_properties(self, properties: Mapping[str, float]) -> np.ndarray:
        out = []
        for prop, (layer, j) in zip(self._properties, self._owner):
            p = layer.parameters[j]
            v = float(properties[prop.name])
            out.append(layer.property_to_coefficient(_suffix(p.name), v) if self._geometric(layer, j) else v)
        return np.array(out)

    def derived_properties(self, theta) -> dict[str, float]:
        """Per layer: relaxation times [s] and unrelaxed moduli [Pa] (see ChainModel)."""
        out = {}
        for layer, vals in zip(self.layers, self.layer_values(np.asarray(theta, dtype=float))):
            for k, v in layer.derived_properties(vals).items():
                out[f"{k}_{layer.name}"] = v
        return out

    def driving_point_output(self, theta) -> np.ndarray:
        """C_v with C_v z = velocity of the first node (power delivered = u C_v z)."""
        return driving_point_velocity_row(self.state_space(np.asarray(theta, dtype=float)))

    def travel_time(self, theta) -> float:
        """sum_l L_l / v_l with v_l = (L_l/n_l) sqrt(k_inst,l / mu_l) (unrelaxed) [s]."""
        total = 0.0
        for layer, vals in zip(self.layers, self.layer_values(np.asarray(theta, dtype=float))):
            total += layer.sample.length / layer.wave_speed(vals)
        return total

    def initial_guess(self, t, u, y) -> np.ndarray:
        theta = np.array([p.typical for p in self._parameters], dtype=float)
        t_arr = first_arrival_time(t, u, y)
        if t_arr is None or t_arr <= 0:
            return theta
        expo = np.array([p.time_exponent for p in self._parameters])
        c = 1.0
        for _ in range(3):  # fixed layers do not scale, so iterate the travel-time match
            c *= self.travel_time(theta * c**expo) / t_arr
        return theta * c**expo


def _suffix(base_name: str) -> str:
    return base_name.rsplit("_", 1)[1]


@hookimpl
def mbus_medium_models():
    return [MediumModelSpec("layered", LayeredChain, LayeredChain.summary)]
