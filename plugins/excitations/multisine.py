"""``multisine`` excitation: a sum of sines on a chosen frequency grid, Schroeder-phased.

With period T_p = n_samples / (periods * sample_rate) the grid is made of multiples of the
line spacing f0 = 1 / T_p, so every period of the record holds a whole number of cycles of
every line (no leakage: the DFT of one period has power on the grid lines only):

    u(t) = c * sum_{k=1..K} cos(2 pi f_k t + phi_k),     f_k = m_k f0

Lines: every ``step``-th multiple of f0 in [f_min, f_max] (``harmonics: odd`` keeps odd
multiples only), or an explicit ``frequencies`` list (each a multiple of f0). Phases:
``schroeder`` phi_k = -pi k (k - 1) / K (Schroeder 1970; low crest factor for equal
amplitudes, about 1.4-1.8), ``random`` (uniform, seeded) or ``zero`` (crest factor sqrt(2K),
the worst case). c scales the peak of the record to ``amplitude``.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from mbus_framework.interfaces.excitation import DesignedExcitation, ExcitationOptions
from mbus_framework.interfaces.hookspecs import ExcitationSpec, hookimpl
from mbus_plugins.excitations.bounds import Amplitude, RecordSamples, SampleRate


class MultisineOptions(ExcitationOptions):
    f_min: float = Field(0.3e6, ge=0, description="lowest line [Hz] (grid option)")
    f_max: float = Field(0.7e6, gt=0, description="highest line [Hz] (grid option)")
    step: int = Field(1, ge=1, description="use every step-th multiple of the line spacing")
    harmonics: Literal["all", "odd"] = Field("all", description="odd: keep odd multiples of the line spacing only")
    frequencies: list[float] | None = Field(
        None, description="explicit lines [Hz], multiples of 1/period (replaces f_min/f_max/step)"
    )
    phases: Literal["schroeder", "random", "zero"] = Field("schroeder", description="phase choice")
    seed: int = Field(0, ge=0, description="seed of random phases (numpy seeds are non-negative)")
    amplitude: Amplitude = Field(1.0, description="peak of the record [N or V]")
    sample_rate: SampleRate = Field(25.0e6, description="sampling rate [Hz]")
    n_samples: RecordSamples = Field(5000, description="record length [samples]")
    periods: int = Field(1, ge=1, description="whole periods in the record (n_samples must be divisible)")

    @model_validator(mode="after")
    def _grid(self):
        if self.n_samples % self.periods:
            raise ValueError(f"n_samples {self.n_samples} is not divisible by periods {self.periods}")
        if self.frequencies is None and self.f_min > self.f_max:
            raise ValueError("f_min must not exceed f_max")
        if self.frequencies is None and self.f_min >= self.sample_rate / 2:
            raise ValueError(f"f_min must stay below the Nyquist frequency {self.sample_rate / 2:g} Hz")
        lines = self.lines()
        if lines.size == 0:
            raise ValueError(f"no grid line between f_min and f_max (line spacing {self.line_spacing:g} Hz)")
        if lines.max() * self.line_spacing >= self.sample_rate / 2:
            raise ValueError(f"lines must stay below the Nyquist frequency {self.sample_rate / 2:g} Hz")
        return self

    @property
    def period_samples(self) -> int:
        return self.n_samples // self.periods

    @property
    def line_spacing(self) -> float:
        """f0 = 1 / T_p [Hz]."""
        return self.sample_rate / self.period_samples

    def lines(self) -> np.ndarray:
        """Multiples m_k of the line spacing (integers, ascending)."""
        f0 = self.line_spacing
        if self.frequencies is not None:
            m = np.asarray(self.frequencies, dtype=float) / f0
            bad = np.abs(m - np.round(m)) > 1e-6 * np.maximum(1.0, m)
            if np.any(bad) or np.any(np.round(m) < 1):
                f = np.asarray(self.frequencies)[bad | (np.round(m) < 1)][0]
                raise ValueError(f"frequency {f:g} Hz is not a positive multiple of the line spacing {f0:g} Hz")
            return np.unique(np.round(m).astype(np.int64))
        first = max(1, int(np.ceil(self.f_min / f0 - 1e-9)))
        last = int(np.floor(min(self.f_max, self.sample_rate) / f0 + 1e-9))  # lines above Nyquist are refused
        m = np.arange(first, last + 1, self.step, dtype=np.int64)
        return m[m % 2 == 1] if self.harmonics == "odd" else m


class Multisine(DesignedExcitation):
    """Sum of equal-amplitude cosines on a grid of multiples of 1/period."""

    Options = MultisineOptions
    summary = "Schroeder-phased multisine on a chosen frequency grid"

    def __init__(self, options):
        super().__init__(options)
        o = self.options
        self.multiples = o.lines()
        K = self.multiples.size
        k = np.arange(1, K + 1)
        if o.phases == "schroeder":
            self.phi = -np.pi * k * (k - 1) / K
        elif o.phases == "random":
            self.phi = np.random.default_rng(o.seed).uniform(-np.pi, np.pi, K)
        else:
            self.phi = np.zeros(K)
        t = np.arange(o.period_samples) / o.sample_rate
        self.scale = o.amplitude / float(np.max(np.abs(self._raw(t))))

    def _raw(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        f = self.multiples * self.options.line_spacing
        out = np.zeros_like(t)
        for fk, pk in zip(f, self.phi):  # K lines; a loop keeps memory at O(N)
            out += np.cos(2 * np.pi * fk * t + pk)
        return out

    def signal(self, t: np.ndarray) -> np.ndarray:
        return self.scale * self._raw(t)

    def describe(self) -> dict:
        o = self.options
        f = self.multiples * o.line_spacing
        return {
            "n_lines": int(f.size),
            "line_spacing_hz": o.line_spacing,
            "f_first_hz": float(f[0]),
            "f_last_hz": float(f[-1]),
            "phases": o.phases,
            "period_s": o.period_samples / o.sample_rate,
            "period_samples": float(o.period_samples),
            "periods": o.periods,
        }


@hookimpl
def mbus_excitations():
    return [ExcitationSpec("multisine", Multisine, Multisine.summary)]
