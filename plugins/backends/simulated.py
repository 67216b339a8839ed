"""``simulated`` backend: a virtual rig with a known 'true' medium.

The designed excitation u [N] drives the true medium (by default the model being fitted,
optionally another model or element count given under ``medium``), simulated exactly
(:mod:`mbus_framework.simulation`). Noise is explicit:

    y = y_true + e,   e ~ N(0, sigma^2) i.i.d.,
    y_true(t) = g * y_medium(t - tau)    (g = input_gain, tau = delay; defaults 1 and 0)
    sigma = relative_std * RMS(y_true)   (or absolute_std [N] when given)

and optionally the recorded input is noisy too (input_relative_std * RMS(u)). The noise
stream comes from ``numpy.random.default_rng(seed)``, so every simulated run is reproducible.
This is how "noise 10 %" of Table 3.1 is read (DESIGN.md, Section 2).
"""
from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.backend import AcquisitionContext, Backend, Measurement
from mbus_framework.config import validate_options
from mbus_framework.errors import ConfigError
from mbus_framework.hookspecs import BackendSpec, hookimpl
from mbus_framework.nuisance import delayed_prediction
from mbus_framework.simulation import simulate


class NoiseOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["gaussian"] = "gaussian"
    relative_std: float = Field(0.05, ge=0, description="std of output noise / RMS of noise-free output")
    absolute_std: float | None = Field(None, ge=0, description="std of output noise [N]; overrides relative_std")
    input_relative_std: float = Field(0.0, ge=0, description="std of input noise / RMS of the input")


class MediumRef(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    options: dict[str, Any] = Field(default_factory=dict)


class SimulatedOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    truth: dict[str, float] = Field(description="true parameters, or true material properties, of the medium")
    medium: MediumRef | None = Field(None, description="true medium model if not the fitted one")
    noise: NoiseOptions = Field(default_factory=NoiseOptions)
    seed: int = Field(0, description="seed of the noise generator")
    hold: Literal["zoh", "foh"] = Field("zoh", description="input hold used to simulate the truth")
    input_gain: float = Field(1.0, gt=0, description="true force per recorded input unit [N/unit]")
    delay: float = Field(0.0, ge=0, description="true trigger offset of the received wave [s]")


class SimulatedBackend(Backend):
    """Virtual rig: exact simulation of a true medium plus explicit Gaussian noise."""

    Options = SimulatedOptions
    summary = "virtual rig: true medium + Gaussian noise (seeded)"

    def acquire(self, context: AcquisitionContext) -> Measurement:
        o = self.options
        medium = context.model
        if o.medium is not None:
            spec = context.registry.get("model", o.medium.name)
            opts = validate_options(spec.implementation.Options, o.medium.options, "backend.options.medium.options")
            medium = spec.implementation(context.sample, opts)
        theta = medium.theta_from_mapping(o.truth, "backend.options.truth")
        t, u = context.excitation.t, context.excitation.u
        dt = float(t[1] - t[0])
        if o.delay > 0:
            if o.hold != "zoh":
                raise ConfigError(f"{context.config_path}: backend.options.delay needs hold: zoh")
            y_true = delayed_prediction(medium, theta, u, dt, o.input_gain, o.delay)
        else:
            y_true = o.input_gain * simulate(medium, theta, u, dt, o.hold)
        rng = np.random.default_rng(o.seed)
        sigma = o.noise.absolute_std if o.noise.absolute_std is not None else o.noise.relative_std * _rms(y_true)
        y = y_true + rng.normal(0.0, sigma, y_true.shape) if sigma > 0 else y_true.copy()
        sigma_u = o.noise.input_relative_std * _rms(u)
        u_meas = u + rng.normal(0.0, sigma_u, u.shape) if sigma_u > 0 else np.array(u, dtype=float)
        same_model = type(medium) is type(context.model) and medium.options == context.model.options
        truth = dict(zip(medium.parameter_names, map(float, theta))) if same_model else None
        meta = {
            "source": "simulated",
            "medium": o.medium.name if o.medium else "(fitted model)",
            "true_parameters": dict(zip(medium.parameter_names, map(float, theta))),
            "true_properties": medium.to_properties(theta),
            "noise_std": float(sigma),
            "input_noise_std": float(sigma_u),
            "seed": o.seed,
            "true_input_gain": o.input_gain,
            "true_delay_s": o.delay,
        }
        return Measurement(t.copy(), u_meas, y, truth=truth, meta=meta)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


@hookimpl
def mbus_backends():
    return [BackendSpec("simulated", SimulatedBackend, SimulatedBackend.summary)]
