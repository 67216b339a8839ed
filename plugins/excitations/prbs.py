"""``prbs`` excitation: maximal-length pseudo-random binary sequence (Section 3.4.4).

An order-n linear-feedback shift register gives a period of 2^n - 1 bits. Each bit lasts
``bit_width`` seconds and takes the level +amplitude or -amplitude; the sequence is sampled
at ``sample_rate`` (a bit edge that falls between samples takes effect at the next sample).
The power spectrum follows the envelope sinc^2(f T_b) with nulls at multiples of 1/T_b; its
-3 dB bandwidth is about 0.443 / T_b (Fig. 3.7).
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.signal import max_len_seq

from mbus_framework.excitation import Excitation, Waveform
from mbus_framework.hookspecs import ExcitationSpec, hookimpl


class PrbsOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    order: int = Field(9, ge=3, le=20, description="LFSR order n; period 2^n - 1 bits")
    bit_width: float = Field(2.5e-6, gt=0, description="duration of one bit [s]")
    amplitude: float = Field(1.0, gt=0, description="level of a bit, +-amplitude [N or V]")
    sample_rate: float = Field(6.25e6, gt=0, description="sampling rate [Hz]")
    n_samples: int | None = Field(None, ge=16, description="record length [samples]")
    duration: float | None = Field(None, gt=0, description="record length [s] (alternative to n_samples)")
    shift: int = Field(0, ge=0, description="start the sequence this many bits in (a different realisation)")

    @model_validator(mode="after")
    def _length(self):
        if self.n_samples is None and self.duration is None:
            self.n_samples = int(round((2**self.order - 1) * self.bit_width * self.sample_rate))
        elif self.n_samples is None:
            self.n_samples = int(round(self.duration * self.sample_rate))
        elif self.duration is not None:
            raise ValueError("give n_samples or duration, not both")
        if self.bit_width * self.sample_rate < 1.0:
            raise ValueError(
                f"bit_width {self.bit_width:g} s is shorter than one sample at {self.sample_rate:g} Hz"
            )
        return self


def mls_bits(order: int) -> np.ndarray:
    """One period of a maximal-length sequence of 0/1 bits (2^order - 1 long)."""
    return max_len_seq(order)[0].astype(np.int8)


class Prbs(Excitation):
    """Maximal-length PRBS sampled on a uniform grid."""

    Options = PrbsOptions
    summary = "maximal-length LFSR pseudo-random binary sequence"

    def waveform(self) -> Waveform:
        o = self.options
        bits = mls_bits(o.order)
        t = np.arange(o.n_samples) / o.sample_rate
        # Bit index of each sample; the tiny offset keeps exact edges on the new bit.
        index = (np.floor(t / o.bit_width + 1e-9).astype(np.int64) + o.shift) % bits.size
        u = o.amplitude * (2.0 * bits[index] - 1.0)
        info = {
            "order": o.order,
            "period_bits": int(bits.size),
            "bit_width_s": o.bit_width,
            "bandwidth_3db_hz": 0.443 / o.bit_width,
        }
        return Waveform(t, u, info)


@hookimpl
def mbus_excitations():
    return [ExcitationSpec("prbs", Prbs, Prbs.summary)]
