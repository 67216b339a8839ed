"""Specific hints for two likely mistakes in a recorded contact-transmission record.

* **Time unit.** Ultrasonic transducers work between about 20 kHz and 50 MHz. An input whose
  median frequency (half its power below, :func:`power_quantile`) lies below 1 kHz or above
  1 GHz was almost surely read with the wrong time unit: a time column in microseconds read as
  seconds puts a 1 MHz burst at 1 Hz. The hint names the factor 10^3k (k = 1, 2, 3) that brings
  the band into the transducer range.
* **Swapped channels.** In contact transmission the output is a delayed, filtered copy of the
  input: the cross-correlation c(k) = sum_n u[n] y[n + k] peaks at a positive lag (the travel
  time). A peak at a negative lag, with the output's onset (first |y| above 10 % of its peak)
  before the input's, means the output leads the input: the channels are likely swapped.

Each hint is one warning naming what to change; a good record gets none.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mbus_framework.engine.physics import onset_index
from mbus_framework.pipeline.recorded_input import power_quantile

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.interfaces.backend import Measurement

TRANSDUCER_BAND_HZ = (20e3, 50e6)
PLAUSIBLE_HZ = (1e3, 1e9)
UNIT = {3: "milliseconds", 6: "microseconds", 9: "nanoseconds"}


def time_unit_hint(u: np.ndarray, dt: float) -> str | None:
    """A one-line hint when the input's band says the time column has the wrong unit."""
    f = power_quantile(np.asarray(u, float), dt, 0.5)
    if not np.isfinite(f) or f <= 0 or PLAUSIBLE_HZ[0] <= f <= PLAUSIBLE_HZ[1]:
        return None
    lo, hi = TRANSDUCER_BAND_HZ
    slow = f < PLAUSIBLE_HZ[0]
    fits = [k for k in (3, 6, 9) if lo <= (f * 10.0**k if slow else f / 10.0**k) <= hi]
    k = fits[0] if fits else min((3, 6, 9), key=lambda k: abs(np.log10(f) + (k if slow else -k) - 6))
    what = (f"is the time in {UNIT[k]}? multiply t by 1e-{k}" if slow
            else f"is the time {10 ** k:g} times too small? multiply t by 1e{k}")
    return (f"time: the input's median frequency is {f:.3g} Hz (sample interval {dt:.3g} s), "
            f"{'far below' if slow else 'far above'} an ultrasonic transducer's band "
            f"({lo / 1e3:g} kHz-{hi / 1e6:g} MHz): {what} (or give the time column in seconds)")


def swapped_channels_hint(u: np.ndarray, y: np.ndarray, dt: float, scope_pair: bool) -> str | None:
    """A one-line hint when the output leads the input (likely swapped channels)."""
    u = np.asarray(u, float) - np.mean(u)
    y = np.asarray(y, float) - np.mean(y)
    n = u.size
    iu, iy = onset_index(u), onset_index(y)
    if n < 16 or iu is None or iy is None or iy >= iu:
        return None
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    c = np.fft.irfft(np.conj(np.fft.rfft(u, nfft)) * np.fft.rfft(y, nfft), nfft)
    k = int(np.argmax(np.abs(c)))
    lag = k if k < n else k - nfft
    if lag >= 0:
        return None
    fix = ("swap backend.options.path and response_path" if scope_pair
           else "swap the u and y columns (backend.options.columns: {u: <output column>, y: <input column>})")
    return (f"channels: the output leads the input (its onset {(iu - iy) * dt:.3g} s earlier, cross-correlation peak "
            f"at lag {lag * dt:.3g} s): the input and output look swapped; {fix}")


def record_hints(m: "Measurement") -> list[str]:
    """The hints that apply to a record (none on a good one)."""
    out = [time_unit_hint(m.u, m.dt),
           swapped_channels_hint(m.u, m.y, m.dt, bool(m.meta.get("response_source")))]
    return [h for h in out if h]
