"""Pre-trigger samples and DC offsets of t,u,y records (text, NPZ, .mat files).

A recorder keeps samples from before the excitation began (the pre-trigger), and an amplifier
or a scope adds a constant offset. The fitted model starts at rest with zero output, so both
would be taken for signal: an offset of 16 % of std(y) made a potato fit 5x worse.

The record starts where the earlier of the two channels leaves its rest,
k_0 = min(k_u, k_y) (:func:`~mbus_plugins.instruments.shots.burst_start` on each channel;
the output may lead the input in a substitution record). With at least :data:`MIN_PRE`
samples before k_0, each channel's pre-trigger mean is its offset,
c_x = mean(x[0:k_0]), and the record becomes x[k_0:] - c_x, t from 0. Fewer pre-trigger
samples leave the record as it is (too few to estimate an offset).
"""
from __future__ import annotations

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.interfaces.backend import MIN_SAMPLES, Measurement
from mbus_plugins.instruments.shots import burst_start

MIN_PRE = 8
"""Fewest pre-trigger samples that are cut and averaged for the offsets."""


def _onset(x: np.ndarray) -> int | None:
    try:
        return burst_start(x, "")
    except DataError:  # a flat channel has no onset
        return None


def remove_pretrigger(m: Measurement, source: str) -> Measurement:
    """The record from its onset with the pre-trigger offsets subtracted; ``meta["pretrigger"]``
    says what was done (``samples``, ``seconds``, ``offset_u``, ``offset_y``)."""
    k_u, k_y = _onset(m.u), _onset(m.y)
    onsets = [k for k in (k_u, k_y) if k is not None]
    start = min(onsets) if onsets else 0
    if start < MIN_PRE:
        m.meta["pretrigger"] = {"samples": 0, "detail": "the record starts at the excitation: nothing removed"}
        return m
    if m.u.size - start < MIN_SAMPLES:
        raise DataError(f"{source}: only {m.u.size - start} samples after the onset at sample {start}; "
                        f"set backend.options.pretrigger: false to fit the record as it is")
    off_u, off_y = float(np.mean(m.u[:start])), float(np.mean(m.y[:start]))
    dt = m.dt
    out = Measurement(m.t[start:] - m.t[start], m.u[start:] - off_u, m.y[start:] - off_y, m.truth, dict(m.meta))
    out.meta["pretrigger"] = {"samples": int(start), "seconds": start * dt, "offset_u": off_u, "offset_y": off_y,
                              "onset_u_samples": k_u, "onset_y_samples": k_y}
    if "time_start_s" in out.meta:
        out.meta["time_start_s"] = float(out.meta["time_start_s"]) + start * dt
    return out

