"""``simulated`` backend: a virtual rig with a known 'true' medium.

The designed excitation u [N] drives the true medium (by default the model being fitted,
optionally another model or element count given under ``medium``), simulated exactly
(:mod:`mbus_framework.engine.simulation`). Noise is explicit:

    y = y_true + e,   e ~ N(0, sigma^2) i.i.d.,
    y_true(t) = g * y_medium(t - tau)    (g = input_gain, tau = delay; defaults 1 and 0)
    sigma = relative_std * RMS(y_true)   (or absolute_std [N] when given)

and optionally the recorded input is noisy too (input_relative_std * RMS(u)). The noise
stream comes from ``numpy.random.default_rng(seed)``, so every simulated run is reproducible.
This is how "noise 10 %" of Table 3.1 is read (DESIGN.md, Section 2).

Optional lab realities (absent options leave the record exactly as above):

* ``transducers``: a virtual transducer pair; u is then the generator voltage. ``kind: filter``
  (the default, :mod:`mbus_plugins.backends.transducers`): y_medium becomes G_R * medium * G_T * u
  (eq. 5.1), simulated exactly as one continuous cascade. ``kind: mechanical``
  (:mod:`mbus_plugins.backends.mechanical_transducers`): lumped piezo elements, plates and
  backings in series with the medium's chain at both ends, one heterogeneous chain.
* ``scope``: 8-bit ADC quantisation of both channels with a vertical range, averaging over
  ``averages`` shots with independent noise, and a trigger delay of both channels. The
  reported ``noise_std`` is then sqrt((sigma^2 + q^2/12) / averages) (q the ADC step; the q^2/12
  part is the dithered-quantisation approximation, valid when sigma is not far below q).
* ``wave``: instead of a lumped model the medium is a lossy, reflection-free plane-wave path of
  the sample's length L, G_M(f; L) = exp(-L alpha(f)) exp(-i 2 pi f L / c) with
  alpha(f) = alpha_1 (f / 1 MHz)^y: the law G_M(nL) = G_M(L)^n that the Chapter 5 calibration
  assumes (water: c = 1482 m/s, alpha_1 = 0.025 Np/m). The delay is exact (ZOH input); the
  attenuation, a zero-phase factor within 1e-3 of 1 in the band for water, is applied by FFT.
  ``truth`` is not used.
"""
from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from scipy import fft as sfft

from mbus_framework.interfaces.backend import AcquisitionContext, Backend, Measurement
from mbus_framework.pipeline.config import format_validation_error, validate_options
from mbus_framework.pipeline.limits import check_parameters
from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.hookspecs import BackendSpec, hookimpl
from mbus_framework.estimation.nuisance import delayed_prediction
from mbus_framework.engine.simulation import simulate
from mbus_plugins.backends.mechanical_transducers import MechanicalTransducerOptions, MechanicalTransducerPair
from mbus_plugins.backends.transducers import ScopeOptions, TransducerPair, TransducerPairOptions, adc, adc_step


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


class WaveOptions(BaseModel):
    """``wave``: plane-wave reference medium (for calibrations), see the module docstring."""

    model_config = ConfigDict(extra="forbid")
    sound_speed: float = Field(1482.0, gt=0, description="phase velocity c [m/s] (water at 20 C: 1482)")
    attenuation: float = Field(0.025, ge=0, description="alpha_1: attenuation at 1 MHz [Np/m] (water: 0.025)")
    attenuation_exponent: float = Field(2.0, ge=0, le=4, description="y in alpha(f) = alpha_1 (f / 1 MHz)^y")

    def response(self, f: np.ndarray, length: float) -> np.ndarray:
        """G_M(i 2 pi f; L) (dimensionless)."""
        f = np.abs(np.asarray(f, dtype=float))
        alpha = self.attenuation * (f / 1e6) ** self.attenuation_exponent
        return np.exp(-length * alpha - 2j * np.pi * f * length / self.sound_speed)


class SimulatedOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    truth: dict[str, float] = Field(description="true parameters, or true material properties, of the medium")
    medium: MediumRef | None = Field(None, description="true medium model if not the fitted one")
    noise: NoiseOptions = Field(default_factory=NoiseOptions)
    seed: int = Field(0, ge=0, description="seed of the noise generator (numpy seeds are non-negative)")
    hold: Literal["zoh", "foh"] = Field("zoh", description="input hold used to simulate the truth")
    input_gain: float = Field(1.0, gt=0, description="true force per recorded input unit [N/unit]")
    delay: float = Field(0.0, ge=0, description="true trigger offset of the received wave [s]")
    transducers: TransducerPairOptions | MechanicalTransducerOptions | None = Field(
        None, description="virtual transducer pair: band-pass filters (kind: filter, the default) or lumped "
        "mechanics around the sample (kind: mechanical)")
    scope: ScopeOptions | None = Field(None, description="ADC quantisation, averaging and trigger delay")
    wave: WaveOptions | None = Field(None, description="plane-wave reference medium instead of a model (calibration)")

    @model_validator(mode="before")
    @classmethod
    def _wave_needs_no_truth(cls, data):
        if isinstance(data, dict) and data.get("wave") is not None and "truth" not in data:
            data = {**data, "truth": {}}
        return data

    @field_validator("transducers", mode="wrap")
    @classmethod
    def _transducer_kind(cls, value, handler):
        """``kind`` picks the pair: filter (the default) or mechanical; errors name the key inside."""
        if not isinstance(value, dict):
            return handler(value)
        kind = value.get("kind", "filter")
        if kind == "filter":  # a ValidationError raised here keeps its key path under transducers
            return TransducerPairOptions.model_validate({k: v for k, v in value.items() if k != "kind"})
        if kind != "mechanical":
            raise ValueError(f"kind: {kind!r} is not a transducer kind; choose filter or mechanical")
        try:
            return MechanicalTransducerOptions.model_validate(value)
        except ValidationError as exc:  # one line naming the key inside transducers
            raise ValueError(format_validation_error(exc, MechanicalTransducerOptions).lstrip(": ")) from None

    @model_validator(mode="after")
    def _check(self):
        if isinstance(self.transducers, MechanicalTransducerOptions) and self.wave is not None:
            raise ValueError("transducers: kind mechanical needs a chain medium, not wave (use kind: filter)")
        if self.wave is not None:
            if self.truth or self.medium is not None:
                raise ValueError("wave replaces the model medium: leave out truth and medium")
            if self.hold != "zoh":
                raise ValueError("wave needs hold: zoh")
        if self.hold != "zoh" and (self.delay > 0 or (self.scope and self.scope.trigger_delay > 0)):
            raise ValueError("delay and scope.trigger_delay need hold: zoh")
        return self


class SimulatedBackend(Backend):
    """Virtual rig: exact simulation of a true medium plus explicit Gaussian noise."""

    Options = SimulatedOptions
    summary = "virtual rig: true medium + Gaussian noise (seeded), optional transducer pair and scope"

    def __init__(self, options):
        super().__init__(options)
        t = options.transducers
        if isinstance(t, MechanicalTransducerOptions):
            self.pair = MechanicalTransducerPair(t)
        else:
            self.pair = TransducerPair(t) if t is not None else None

    # -- the rig's true linear path (for calibration checks and plots) ---------------------------
    def true_transducer_response(self, f: np.ndarray) -> np.ndarray:
        """What a calibration should find: g e^{-i 2 pi f tau} G_TR(f) (1 without transducers)."""
        f = np.asarray(f, dtype=float)
        o = self.options
        pair = self.pair.response(f) if self.pair is not None else np.ones_like(f, dtype=complex)
        return o.input_gain * np.exp(-2j * np.pi * f * o.delay) * pair

    def transducer_identity(self) -> str | None:
        return self.pair.name if self.pair is not None else None

    # -- acquisition ----------------------------------------------------------------------------
    def acquire(self, context: AcquisitionContext) -> Measurement:
        o = self.options
        t, u = context.excitation.t, np.asarray(context.excitation.u, dtype=float)
        dt = float(t[1] - t[0])
        trigger = o.scope.trigger_delay if o.scope is not None else 0.0
        duration = float(t[-1] - t[0])
        if o.delay + trigger >= duration:
            raise ConfigError(f"{context.config_path}: backend.options.delay / scope.trigger_delay: the response "
                              f"arrives {o.delay + trigger:g} s after the record starts, after its end ({duration:g} s)")
        if o.wave is not None:
            medium, theta = None, None
            travel = context.sample.length / o.wave.sound_speed
            if o.delay + trigger + travel >= duration:
                raise ConfigError(f"{context.config_path}: backend.options.wave: the wave through {context.sample.length:g} m "
                                  f"arrives {o.delay + trigger + travel:g} s after the record starts, after its end "
                                  f"({duration:g} s); lengthen the record")
            y_true = self._wave_response(u, dt, context.sample.length, trigger)
        else:
            medium = context.model
            if o.medium is not None:
                spec = context.registry.get("model", o.medium.name)
                opts = validate_options(
                    spec.implementation.Options, o.medium.options, "backend.options.medium.options"
                )
                medium = spec.implementation(context.sample, opts)
            where = f"{context.config_path}: backend.options.truth"
            theta = medium.theta_from_mapping(o.truth, where)
            check_parameters(medium, dict(zip(medium.parameter_names, theta)), where)
            path = self.pair.around(medium) if self.pair is not None else medium
            total_delay = o.delay + trigger
            if total_delay > 0:
                if o.hold != "zoh":
                    raise ConfigError(f"{context.config_path}: backend.options.delay needs hold: zoh")
                y_true = delayed_prediction(path, theta, u, dt, o.input_gain, total_delay)
            else:
                y_true = o.input_gain * simulate(path, theta, u, dt, o.hold)
        u_true = _delay_staircase(u, trigger / dt) if trigger > 0 else u
        rng = np.random.default_rng(o.seed)
        sigma = o.noise.absolute_std if o.noise.absolute_std is not None else o.noise.relative_std * _rms(y_true)
        sigma_u = o.noise.input_relative_std * _rms(u_true)
        meta: dict[str, Any] = {}
        if o.scope is None:
            y = y_true + rng.normal(0.0, sigma, y_true.shape) if sigma > 0 else y_true.copy()
            u_meas = u_true + rng.normal(0.0, sigma_u, u.shape) if sigma_u > 0 else np.array(u_true, dtype=float)
            noise_std = sigma
        else:
            u_meas, y, noise_std, meta["scope"] = self._scope(u_true, y_true, sigma, sigma_u, rng)
        meta = {
            "source": "simulated",
            "noise_std": float(noise_std),
            "input_noise_std": float(sigma_u),
            "seed": o.seed,
            "true_input_gain": o.input_gain,
            "true_delay_s": o.delay,
            **meta,
        }
        truth = None
        if medium is not None:
            same_model = type(medium) is type(context.model) and medium.options == context.model.options
            truth = dict(zip(medium.parameter_names, map(float, theta))) if same_model else None
            meta["medium"] = o.medium.name if o.medium else "(fitted model)"
            meta["true_parameters"] = dict(zip(medium.parameter_names, map(float, theta)))
            meta["true_properties"] = medium.to_properties(theta)
        else:
            meta["medium"] = "plane wave"
            meta["true_parameters"] = {}
            meta["true_properties"] = {
                "sound_speed": o.wave.sound_speed,
                "attenuation_np_per_m_at_1mhz": o.wave.attenuation,
                "attenuation_exponent": o.wave.attenuation_exponent,
                "length_m": context.sample.length,
            }
        if self.pair is not None:
            meta["transducers"] = self.pair.describe()
        if o.scope is not None or self.pair is not None or o.wave is not None:
            meta["noise_std_per_shot"] = float(sigma)
        return Measurement(t.copy(), u_meas, y, truth=truth, meta=meta)

    def _wave_response(self, u: np.ndarray, dt: float, length: float, trigger: float) -> np.ndarray:
        """g G_R G_T G_M(L) u with the plane-wave medium (see the module docstring)."""
        o = self.options
        tau = length / o.wave.sound_speed + o.delay + trigger
        if self.pair is not None:
            y = delayed_prediction(self.pair.alone(), np.zeros(0), u, dt, o.input_gain, tau)
        else:
            y = o.input_gain * _delay_staircase(u, tau / dt)
        if o.wave.attenuation > 0 and length > 0:
            n = y.size
            nfft = sfft.next_fast_len(2 * n, real=True)
            f = sfft.rfftfreq(nfft, dt)
            att = np.exp(-length * o.wave.attenuation * (f / 1e6) ** o.wave.attenuation_exponent)
            y = sfft.irfft(sfft.rfft(y, nfft) * att, nfft)[:n]
        return y

    def _scope(self, u_true, y_true, sigma, sigma_u, rng):
        """Average ``averages`` quantised shots with independent noise; returns (u, y, noise_std, meta)."""
        s = self.options.scope
        out_range = s.output_range or 1.25 * float(np.max(np.abs(y_true)))
        in_range = s.input_range or 1.25 * float(np.max(np.abs(u_true)))
        if out_range <= 0 or in_range <= 0:
            raise ConfigError("backend.options.scope: a channel is all zero; give output_range and input_range")
        y_sum = np.zeros_like(y_true, dtype=float)
        u_sum = np.zeros_like(u_true, dtype=float)
        clipped_y = clipped_u = 0
        for _ in range(s.averages):
            y_shot = y_true + rng.normal(0.0, sigma, y_true.shape) if sigma > 0 else y_true
            u_shot = u_true + rng.normal(0.0, sigma_u, u_true.shape) if sigma_u > 0 else u_true
            yq, cy = adc(y_shot, out_range, s.bits)
            uq, cu = adc(u_shot, in_range, s.bits)
            y_sum += yq
            u_sum += uq
            clipped_y += cy
            clipped_u += cu
        q = adc_step(out_range, s.bits)
        noise_std = float(np.sqrt((sigma**2 + q**2 / 12) / s.averages))
        meta = {
            **s.model_dump(),
            "output_range": out_range,
            "input_range": in_range,
            "output_step": q,
            "input_step": adc_step(in_range, s.bits),
            "clipped_output_samples": clipped_y,
            "clipped_input_samples": clipped_u,
        }
        return u_sum / s.averages, y_sum / s.averages, noise_std, meta


def _delay_staircase(u: np.ndarray, shift: float) -> np.ndarray:
    """Samples of the zero-order-hold staircase of u delayed by ``shift`` samples (rest before)."""
    k = np.floor(np.arange(u.size) - shift + 1e-9).astype(np.int64)
    out = np.zeros(u.size, dtype=float)
    ok = k >= 0
    out[ok] = u[k[ok]]
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


@hookimpl
def mbus_backends():
    return [BackendSpec("simulated", SimulatedBackend, SimulatedBackend.summary)]
