"""``prbs`` excitation: maximal-length pseudo-random binary sequence (Section 3.4.4).

An order-n linear-feedback shift register gives a period of P = 2^n - 1 bits. Each bit lasts
``bit_width`` T_b seconds and takes the level +amplitude or -amplitude; the sequence is sampled
at ``sample_rate`` (a bit edge that falls between samples takes effect at the next sample).
The power spectrum follows the envelope sinc^2(f T_b) with nulls at multiples of 1/T_b; its
-3 dB bandwidth is about 0.443 / T_b (Fig. 3.7). Over whole periods the spectrum is a line
spectrum at multiples of 1 / (P T_b), all lines (except DC) on the envelope.

``inverse_repeat: true`` plays the sequence and then its negative (period 2P bits): the even
lines vanish, so even-order distortion of the rig (which maps s and -s to the same output)
cannot leak onto the excited lines. ``periods`` sets the record length in whole periods
(the first period is a transient; calibration uses the later, steady-state ones).
"""
from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from mbus_framework.interfaces.excitation import DesignedExcitation, ExcitationOptions, record_length
from mbus_framework.interfaces.hookspecs import ExcitationSpec, hookimpl
from mbus_plugins.excitations.bounds import Amplitude, RecordSamples, SampleRate, samples


class PrbsOptions(ExcitationOptions):
    order: int = Field(9, ge=3, le=20, description="LFSR order n; period 2^n - 1 bits")
    bit_width: float = Field(2.5e-6, gt=0, description="duration of one bit [s]")
    amplitude: Amplitude = Field(1.0, description="level of a bit, +-amplitude [N or V]")
    sample_rate: SampleRate = Field(6.25e6, description="sampling rate [Hz]")
    n_samples: RecordSamples | None = Field(None, description="record length [samples]")
    duration: float | None = Field(None, gt=0, description="record length [s] (alternative to n_samples)")
    periods: int | None = Field(
        None, ge=1, le=1000, description="record length in whole periods (alternative to n_samples)"
    )
    inverse_repeat: bool = Field(False, description="follow the sequence by its negative (period 2(2^n - 1) bits)")
    shift: int = Field(0, ge=0, description="start the sequence this many bits in (a different realisation)")

    @property
    def period_bits(self) -> int:
        """Bits in one period of the played signal: 2^n - 1, doubled with inverse_repeat."""
        return (2**self.order - 1) * (2 if self.inverse_repeat else 1)

    @model_validator(mode="after")
    def _length(self):
        one_period = self.period_bits * self.bit_width * self.sample_rate
        if self.periods is not None and (self.n_samples is not None or self.duration is not None):
            raise ValueError("give one of n_samples, duration or periods")
        default = 0
        if self.n_samples is None and self.duration is None:
            default = samples((self.periods or 1) * one_period, "record of whole periods")
        if self.n_samples is None and self.duration is not None:
            samples(self.duration * self.sample_rate, "record (duration x sample_rate)")
        self.n_samples = record_length(self.n_samples, self.duration, self.sample_rate, default)
        if self.bit_width * self.sample_rate < 1.0:
            raise ValueError(
                f"bit_width {self.bit_width:g} s is shorter than one sample at {self.sample_rate:g} Hz"
            )
        if self.n_samples < 16:
            raise ValueError(f"record of {self.n_samples} samples is too short (at least 16)")
        return self


#: Feedback taps of the Fibonacci shift register per order (the first listing of
#: newwaveinstruments.com's m-sequence tables, the same as scipy.signal.max_len_seq's).
MLS_TAPS = {2: (1,), 3: (2,), 4: (3,), 5: (3,), 6: (5,), 7: (6,), 8: (7, 6, 1), 9: (5,), 10: (7,), 11: (9,),
            12: (11, 10, 4), 13: (12, 11, 8), 14: (13, 12, 2), 15: (14,), 16: (15, 13, 4)}


def mls_bits(order: int) -> np.ndarray:
    """One period of a maximal-length sequence of 0/1 bits (2^order - 1 long), starting from
    the all-ones register: s[n + m] = s[n] xor (xor over taps t of s[n + t]), s[0..m-1] = 1
    (m = order). Orders above 16 come from scipy.signal.max_len_seq (same sequence)."""
    if order not in MLS_TAPS:
        from scipy.signal import max_len_seq  # imports scipy.stats (about 0.5 s): only for long sequences

        return max_len_seq(order)[0].astype(np.int8)
    n = (1 << order) - 1
    s = bytearray(n + order)
    s[:order] = b"\x01" * order
    taps = MLS_TAPS[order]
    for i in range(n):
        bit = s[i]
        for t in taps:
            bit ^= s[i + t]
        s[i + order] = bit
    return np.frombuffer(bytes(s[:n]), dtype=np.int8).copy()


class Prbs(DesignedExcitation):
    """Maximal-length PRBS sampled on a uniform grid."""

    Options = PrbsOptions
    summary = "maximal-length LFSR pseudo-random binary sequence (periods, inverse-repeat)"

    def signal(self, t: np.ndarray) -> np.ndarray:
        o = self.options
        levels = 2.0 * mls_bits(o.order) - 1.0
        p = levels.size
        # Bit index of each time; the tiny offset keeps exact edges on the new bit.
        j = (np.floor(np.asarray(t) / o.bit_width + 1e-9).astype(np.int64) + o.shift % o.period_bits) % o.period_bits
        sign = np.where(j >= p, -1.0, 1.0) if o.inverse_repeat else 1.0
        return o.amplitude * sign * levels[j % p]

    def describe(self) -> dict:
        o = self.options
        period_s = o.period_bits * o.bit_width
        return {
            "order": o.order,
            "period_bits": int(2**o.order - 1),
            "bit_width_s": o.bit_width,
            "bandwidth_3db_hz": 0.443 / o.bit_width,
            "first_null_hz": 1.0 / o.bit_width,
            "inverse_repeat": o.inverse_repeat,
            "period_s": period_s,
            "period_samples": period_s * o.sample_rate,
            "periods": o.n_samples / (period_s * o.sample_rate),
            "line_spacing_hz": 1.0 / period_s,
        }


@hookimpl
def mbus_excitations():
    return [ExcitationSpec("prbs", Prbs, Prbs.summary)]
