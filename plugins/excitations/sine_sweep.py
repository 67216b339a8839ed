"""``sine_sweep`` excitation: linear or logarithmic chirp (swept sine).

Over the sweep duration T (from t = 0) the instantaneous frequency f_i(t) = (1 / 2 pi) d phi / dt is

    linear:       f_i(t) = f0 + (f1 - f0) t / T,       phi(t) = 2 pi (f0 t + (f1 - f0) t^2 / (2 T))
    logarithmic:  f_i(t) = f0 k^(t/T),  k = f1 / f0,    phi(t) = 2 pi f0 T (k^(t/T) - 1) / ln k

and u(t) = A w(t) sin(phi(t)), with w a Tukey (cosine-tapered) window whose tapered fraction
is ``taper`` (0 = rectangular). After the sweep the generator rests (u = 0) until the end of
the record. The power spectrum is flat between f0 and f1 for a linear sweep and falls as
1/f for a logarithmic one (equal time per octave); the crest factor is sqrt(2) untapered.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from mbus_framework.interfaces.excitation import DesignedExcitation, ExcitationOptions, record_length
from mbus_framework.interfaces.hookspecs import ExcitationSpec, hookimpl
from mbus_plugins.excitations.bounds import Amplitude, RecordSamples, SampleRate, samples


class SineSweepOptions(ExcitationOptions):
    kind: Literal["linear", "log"] = Field("linear", description="frequency law of the sweep")
    f_start: float = Field(0.3e6, ge=0, description="instantaneous frequency at t = 0 [Hz]")
    f_stop: float = Field(0.7e6, ge=0, description="instantaneous frequency at the end of the sweep [Hz]")
    sweep_duration: float | None = Field(None, gt=0, description="sweep length T [s] (default: the record)")
    amplitude: Amplitude = Field(1.0, description="peak amplitude A [N or V]")
    taper: float = Field(0.0, ge=0, le=1, description="fraction of the sweep inside the Tukey cosine tapers")
    sample_rate: SampleRate = Field(25.0e6, description="sampling rate [Hz]")
    n_samples: RecordSamples | None = Field(None, description="record length [samples] (default 5000)")
    duration: float | None = Field(None, gt=0, description="record length [s] (alternative to n_samples)")

    @model_validator(mode="after")
    def _check(self):
        default = 5000
        if self.sweep_duration:
            default = samples(self.sweep_duration * self.sample_rate, "sweep (sweep_duration x sample_rate)")
        if self.n_samples is None and self.duration is not None:
            samples(self.duration * self.sample_rate, "record (duration x sample_rate)")
        self.n_samples = record_length(self.n_samples, self.duration, self.sample_rate, default)
        if self.n_samples < 16:
            raise ValueError(f"record of {self.n_samples} samples is too short (at least 16)")
        if self.sweep_duration is None:
            self.sweep_duration = self.n_samples / self.sample_rate
        nyquist = self.sample_rate / 2
        if max(self.f_start, self.f_stop) >= nyquist:
            raise ValueError(f"sweep frequencies must stay below the Nyquist frequency {nyquist:g} Hz")
        if self.f_start == self.f_stop:
            raise ValueError("f_start and f_stop must differ")
        if self.kind == "log" and min(self.f_start, self.f_stop) <= 0:
            raise ValueError("a logarithmic sweep needs f_start > 0 and f_stop > 0")
        return self


class SineSweep(DesignedExcitation):
    """Linear or logarithmic chirp with an optional Tukey taper."""

    Options = SineSweepOptions
    summary = "linear or logarithmic chirp (start/stop frequency, duration, taper)"

    def instantaneous_frequency(self, t: np.ndarray) -> np.ndarray:
        """f_i(t) [Hz] within the sweep (analytic)."""
        o = self.options
        x = np.asarray(t, dtype=float) / o.sweep_duration
        if o.kind == "linear":
            return o.f_start + (o.f_stop - o.f_start) * x
        return o.f_start * (o.f_stop / o.f_start) ** x

    def phase(self, t: np.ndarray) -> np.ndarray:
        """phi(t) [rad], phi(0) = 0."""
        o = self.options
        t = np.asarray(t, dtype=float)
        T = o.sweep_duration
        if o.kind == "linear":
            return 2 * np.pi * (o.f_start * t + (o.f_stop - o.f_start) * t**2 / (2 * T))
        k = o.f_stop / o.f_start
        return 2 * np.pi * o.f_start * T * np.expm1(np.log(k) * t / T) / np.log(k)

    def signal(self, t: np.ndarray) -> np.ndarray:
        o = self.options
        t = np.asarray(t, dtype=float)
        T = o.sweep_duration
        inside = (t >= 0) & (t < T)
        u = np.zeros_like(t)
        u[inside] = o.amplitude * np.sin(self.phase(t[inside])) * _tukey(t[inside] / T, o.taper)
        return u

    def describe(self) -> dict:
        o = self.options
        return {
            "kind": o.kind,
            "f_start_hz": o.f_start,
            "f_stop_hz": o.f_stop,
            "sweep_duration_s": o.sweep_duration,
            "sweep_rate": (o.f_stop - o.f_start) / o.sweep_duration if o.kind == "linear"
            else np.log10(o.f_stop / o.f_start) / o.sweep_duration,
            "sweep_rate_unit": "Hz/s" if o.kind == "linear" else "decades/s",
            "taper": o.taper,
        }


def _tukey(x: np.ndarray, alpha: float) -> np.ndarray:
    """Tukey window evaluated at x in [0, 1) (continuous form of scipy's ``tukey``)."""
    if alpha <= 0:
        return np.ones_like(x)
    w = np.ones_like(x)
    half = alpha / 2
    lo, hi = x < half, x > 1 - half
    w[lo] = 0.5 * (1 - np.cos(np.pi * x[lo] / half))
    w[hi] = 0.5 * (1 - np.cos(np.pi * (1 - x[hi]) / half))
    return w



@hookimpl
def mbus_excitations():
    return [ExcitationSpec("sine_sweep", SineSweep, SineSweep.summary)]
