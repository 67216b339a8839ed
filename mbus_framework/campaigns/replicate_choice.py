"""``campaign.replicates: auto``: average a sample's replicate records, or fit them jointly?

Averaging is only right when every replicate saw the same rig: the same input gain g and delay
tau (y_r(t) = g_r * y(t - tau_r)). The records are compared with the first one:

* gain: the transfer amplitude a_r = RMS(y_r) / RMS(u_r); the replicates differ in gain when
  max_r a_r / min_r a_r > 1 + :data:`GAIN_TOLERANCE` (measurement noise of a few per cent moves
  a_r by far less than 10 %);
* delay: the lag l_r (samples) maximising the cross-correlation of y_r with y_1, minus the same
  lag of the inputs u_r and u_1 (a trigger offset of both channels is no rig difference); the
  replicates differ in delay when |l_r| > :data:`LAG_TOLERANCE` samples.

Records of different length or time step cannot be averaged: ``joint``. Either difference
chooses ``joint`` (shared properties, per-replicate input gain and delay),
otherwise ``average``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mbus_framework.interfaces.backend import Measurement

#: relative spread of the replicates' RMS(y)/RMS(u) beyond which they differ in gain
GAIN_TOLERANCE = 0.10
#: cross-correlation lag [samples] beyond which replicates differ in delay
LAG_TOLERANCE = 1


@dataclass(frozen=True)
class Choice:
    """``mode`` "joint" or "average"; ``gain_ratio`` max/min transfer amplitude; ``max_lag``
    largest |lag| in samples; ``reason`` one line for the table and the summary."""

    mode: str
    gain_ratio: float
    max_lag: int
    reason: str


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def lag(a: np.ndarray, b: np.ndarray) -> int:
    """The shift k (samples) with b(t) ~ a(t - k): argmax of the FFT cross-correlation."""
    n = min(len(a), len(b))
    a, b = np.asarray(a[:n], float) - np.mean(a[:n]), np.asarray(b[:n], float) - np.mean(b[:n])
    size = 1 << int(np.ceil(np.log2(2 * n)))
    xc = np.fft.irfft(np.conj(np.fft.rfft(a, size)) * np.fft.rfft(b, size), size)
    k = int(np.argmax(xc))
    return k - size if k > size // 2 else k


def choose(records: Sequence[Measurement]) -> Choice:
    """Joint when the replicates differ in gain or delay (module docstring), else average."""
    first = records[0]
    if any(len(m.t) != len(first.t) or abs(m.dt - first.dt) > 1e-6 * first.dt for m in records[1:]):
        return Choice("joint", math.nan, 0, "auto: joint, the records differ in length or sampling "
                                            "(they cannot be averaged)")
    amps = [_rms(m.y) / (_rms(m.u) or 1.0) for m in records]
    ratio = max(amps) / min(amps) if min(amps) > 0 else float("inf")
    lags = [lag(first.y, m.y) - lag(first.u, m.u) for m in records[1:]]
    max_lag = max((abs(k) for k in lags), default=0)
    gain = ratio > 1.0 + GAIN_TOLERANCE
    delay = max_lag > LAG_TOLERANCE
    if gain or delay:
        why = [f"gains differ (RMS ratio {ratio:.3g} > {1 + GAIN_TOLERANCE:g})"] if gain else []
        why += [f"delays differ ({max_lag} samples > {LAG_TOLERANCE})"] if delay else []
        return Choice("joint", ratio, max_lag, "auto: joint, " + " and ".join(why))
    return Choice("average", ratio, max_lag, f"auto: average, same gain (RMS ratio {ratio:.3g}) and delay "
                                             f"(lag {max_lag} samples)")
