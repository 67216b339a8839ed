"""Excitation interface: a designed input waveform, its spectrum, crest factor and quantisation.

An excitation plugin subclasses :class:`Excitation` and returns a :class:`Waveform` (times t [s]
from 0 on a uniform grid, values u). Most built-ins subclass :class:`DesignedExcitation`: they
write the ideal continuous-time signal u(t) once (:meth:`DesignedExcitation.signal`) and get
the record grid, the crest factor and the generator quantisation for free.

Generator quantisation (the ``quantize:`` sub-option every built-in excitation shares)
------------------------------------------------------------------------------------
An arbitrary-waveform generator plays integer codes at its own point rate and holds each
point (zero-order hold). With ``max_code`` M (2^(bits-1) - 1, i.e. +-2047 for the 12-bit
SRS DS340), point rate r_dac (the requested ``rate`` rounded to ``clock`` / N, N integer) and
full scale A_fs (default: the peak |u| of the ideal signal, as the DS340 scales its
``AMPL``):

    code_j  = clip(round(u(j / r_dac) / A_fs * M), -M, M)
    u_q(t)  = code_floor(t r_dac) * A_fs / M

and the record is u_q sampled at the record's sample rate. The quantisation step is A_fs / M;
without rate rounding and with r_dac equal to the sample rate the error is at most half a
step per sample. What was done is reported in ``Waveform.info['quantize']``.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any, Callable, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from mbus_framework.interfaces.model import NoOptions
from mbus_framework.interfaces.waveform import Spectrum, Waveform, crest_factor, power_spectrum  # noqa: F401 - part of this interface


class QuantizeOptions(BaseModel):
    """``quantize``: play the waveform as a generator's integer codes on its point-rate grid."""

    model_config = ConfigDict(extra="forbid")
    bits: int = Field(12, ge=2, le=24, description="DAC resolution; codes span +-(2^(bits-1) - 1)")
    max_code: int | None = Field(
        None, ge=1, description="largest code magnitude (default 2^(bits-1) - 1, e.g. 2047 for the DS340)"
    )
    rate: float | None = Field(
        None, gt=0, description="requested point rate [Hz] (default: the record's sample rate)"
    )
    clock: float | None = Field(
        None, gt=0, description="generator clock [Hz]; the point rate is rounded to clock / N, N integer"
    )
    full_scale: float | None = Field(
        None, gt=0, description="amplitude of the largest code (default: the ideal waveform's peak)"
    )

    @model_validator(mode="after")
    def _codes(self):
        limit = 2 ** (self.bits - 1) - 1
        if self.max_code is None:
            self.max_code = limit
        elif self.max_code > limit:
            raise ValueError(f"max_code {self.max_code} needs more than {self.bits} bits (at most {limit})")
        return self

    def point_rate(self, sample_rate: float) -> tuple[float, int | None]:
        """(actual point rate [Hz], clock divider N or None)."""
        rate = self.rate or sample_rate
        if self.clock is None:
            return float(rate), None
        n = max(1, int(round(self.clock / rate)))
        return self.clock / n, n


def quantize_waveform(
    w: Waveform, q: QuantizeOptions, signal: Callable[[np.ndarray], np.ndarray] | None = None
) -> Waveform:
    """``w`` as played by a generator with options ``q`` (see the module docstring).

    ``signal`` evaluates the ideal waveform at arbitrary times; without it the record's own
    samples are held (zero-order) between sample instants.
    """
    n, dt = len(w.u), w.dt
    r, divider = q.point_rate(1.0 / dt)
    m = max(1, int(math.ceil(n * dt * r - 1e-9)))  # points covering [0, n dt)
    t_dac = np.arange(m) / r
    if signal is not None:
        ideal = np.asarray(signal(t_dac), dtype=float)
    else:
        ideal = w.u[np.clip(np.floor(t_dac / dt + 1e-9).astype(np.int64), 0, n - 1)]
    peak = float(np.max(np.abs(ideal))) if ideal.size else 0.0
    full_scale = q.full_scale or peak
    if full_scale <= 0 or not np.isfinite(full_scale):
        raise ValueError("cannot quantise an all-zero or non-finite waveform")
    step = full_scale / q.max_code
    codes = np.clip(np.round(ideal / step), -q.max_code, q.max_code).astype(np.int64)
    index = np.clip(np.floor(w.t * r + 1e-9).astype(np.int64), 0, m - 1)
    u = codes[index] * step
    err = u - w.u
    info = dict(w.info)
    info["quantize"] = {
        "bits": q.bits,
        "max_code": int(q.max_code),
        "point_rate_hz": float(r),
        "clock_divider": divider,
        "full_scale": float(full_scale),
        "step": float(step),
        "n_points": int(m),
        "clipped_points": int(np.sum(np.abs(ideal) > full_scale * (1 + 1e-12))),
        "rms_error": float(np.sqrt(np.mean(err**2))),
        "max_error": float(np.max(np.abs(err))),
    }
    info["crest_factor"] = crest_factor(u)
    return Waveform(w.t, u, info)


class Excitation(ABC):
    """Base class of excitation plugins; ``options`` is an instance of ``Options``."""

    Options: ClassVar[type[BaseModel]] = NoOptions
    summary: ClassVar[str] = ""

    def __init__(self, options: BaseModel):
        self.options = options

    @abstractmethod
    def waveform(self) -> Waveform:
        """The designed excitation samples."""

    def spectrum(self) -> Spectrum:
        w = self.waveform()
        return power_spectrum(w.u, w.dt)

    def crest_factor(self) -> float:
        """max|u| / RMS(u) of :meth:`waveform`."""
        return crest_factor(self.waveform().u)


class ExcitationOptions(BaseModel):
    """Options every built-in excitation shares: the generator quantisation."""

    model_config = ConfigDict(extra="forbid")
    quantize: QuantizeOptions | None = Field(
        None, description="play as a generator's integer codes on its point-rate grid (e.g. bits: 12)"
    )


class DesignedExcitation(Excitation):
    """An excitation given by its ideal signal u(t); the record is u(k / sample_rate), k < n_samples.

    Subclasses implement :meth:`signal` and :meth:`describe`; their ``Options`` derive from
    :class:`ExcitationOptions` and provide ``sample_rate`` [Hz] and ``n_samples``.
    """

    @abstractmethod
    def signal(self, t: np.ndarray) -> np.ndarray:
        """Ideal waveform at times t [s] (t >= 0)."""

    def describe(self) -> dict[str, Any]:
        """Design facts for ``Waveform.info`` (scalars only: they go to result.json)."""
        return {}

    def grid(self) -> tuple[int, float]:
        """(n_samples, sample_rate [Hz]) of the record; default: from the options."""
        return int(self.options.n_samples), float(self.options.sample_rate)

    def waveform(self) -> Waveform:
        n, fs = self.grid()
        t = np.arange(n) / fs
        u = np.asarray(self.signal(t), dtype=float)
        info = self.describe()
        info["crest_factor"] = crest_factor(u)
        w = Waveform(t, u, info)
        q = getattr(self.options, "quantize", None)
        return quantize_waveform(w, q, self.signal) if q is not None else w


def record_length(n_samples: int | None, duration: float | None, sample_rate: float, default: int) -> int:
    """n_samples, or round(duration * sample_rate), or ``default``; both given is an error."""
    if n_samples is not None and duration is not None:
        raise ValueError("give n_samples or duration, not both")
    if n_samples is not None:
        return int(n_samples)
    if duration is not None:
        return int(round(duration * sample_rate))
    return int(default)
