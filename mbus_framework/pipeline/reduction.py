"""Fitting part of a long record: a time window and/or an anti-aliased decimation
(the ``estimation`` config section).

* ``window: [start_s, stop_s]`` keeps the samples with start_s <= t < stop_s (t from the
  record's first sample). The model starts at rest, so a window should start where the rig
  is at rest (0 s for a record that starts before the excitation).
* ``decimate: q`` low-passes input and output with the same zero-phase FIR filter h (cut-off
  0.8 of the new Nyquist frequency 1/(2 q dt), Hamming window, 20 q + 1 taps) and keeps every
  q-th sample. The medium model is linear and time-invariant, so filtering both sides keeps
  y = H u exact: h * y = H (h * u). The record is taken as at rest before its first sample
  (zero padding); the last 10 q samples, whose filtered values need samples past the record's
  end, are dropped. The fit then sees the band below 0.4 / (q dt) only, at 1/q of the cost
  per evaluation; choose q so that the signal's band stays below it.

Both cost O(N log N) (FFT convolution) and run before the compensator, so every later stage
sees one consistent record at the new time step.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.backend import MIN_SAMPLES, Measurement

#: Half-length of the anti-aliasing filter in output samples (taps = 2 HALF q + 1).
HALF = 10


def antialias_filter(q: int) -> np.ndarray:
    """Zero-phase low-pass FIR taps (odd length 2 HALF q + 1, unit DC gain), cut-off 0.8 of
    the new Nyquist frequency, as a fraction of the old one: 0.8 / q."""
    from scipy.signal import firwin

    return firwin(2 * HALF * q + 1, 0.8 / q, window="hamming")


def decimate(x: np.ndarray, q: int) -> np.ndarray:
    """x filtered by :func:`antialias_filter` (zero padding before the start), every q-th
    sample, the last HALF q samples dropped; q = 1 returns x."""
    if q == 1:
        return x
    from scipy.signal import oaconvolve

    h = antialias_filter(q)
    lag = (h.size - 1) // 2
    filtered = oaconvolve(x, h)[lag: lag + x.size - lag]  # zero-phase, complete part only
    return filtered[::q]


def reduce_record(m: Measurement, settings: Any, source: str) -> tuple[Measurement, dict | None]:
    """The record to fit and what was done to it (None when nothing); ``settings`` is the
    config's ``estimation`` section. Errors are one line naming ``source`` and the key."""
    window, q = settings.window, settings.decimate
    if window is None and q == 1:
        return m, None
    t, u, y = m.t, m.u, m.y
    n0 = t.size
    if window is not None:
        start, stop = window
        keep = (t - t[0] >= start) & (t - t[0] < stop)
        if keep.sum() < MIN_SAMPLES:
            raise ConfigError(f"{source}: estimation.window: [{start:g}, {stop:g}] s holds {int(keep.sum())} samples "
                              f"of the {(t[-1] - t[0]):.4g} s record (at least {MIN_SAMPLES} needed)")
        t, u, y = t[keep], u[keep], y[keep]
    if q > 1:
        n = (t.size - HALF * q + q - 1) // q if t.size > HALF * q else 0
        if n < MIN_SAMPLES:
            raise ConfigError(f"{source}: estimation.decimate: {q} leaves {max(n, 0)} of {t.size} samples "
                              f"(at least {MIN_SAMPLES} needed); use a smaller factor")
        u, y = decimate(u, q), decimate(y, q)
    dt = float(m.t[1] - m.t[0]) * q
    t = np.arange(u.size) * dt
    info = {"window_s": list(window) if window is not None else None, "decimate": q,
            "n_samples": [int(n0), int(u.size)], "dt_s": dt,
            "band_hz": 0.4 / dt if q > 1 else None}
    meta = dict(m.meta, reduction=info)
    return Measurement(t, u, y, truth=m.truth, meta=meta), info
