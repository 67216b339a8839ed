"""Model-independent physics read off a measured record (for initial values)."""
from __future__ import annotations

import numpy as np

from mbus_framework.engine.moving import moving_average

#: Record length [samples] up to which the arrival detector's windows grow with the record.
REFERENCE_SAMPLES = 6000


def onset_index(x: np.ndarray, fraction: float = 0.1) -> int | None:
    """First index where |x| exceeds ``fraction`` of its maximum, or None for a flat record."""
    a = np.abs(np.asarray(x, dtype=float))
    peak = a.max(initial=0.0)
    if not np.isfinite(peak) or peak == 0.0:
        return None
    return int(np.argmax(a > fraction * peak))


def first_arrival_time(t: np.ndarray, u: np.ndarray, y: np.ndarray, fraction: float = 0.25) -> float | None:
    """Time of flight [s]: onset of the received wave minus onset of the excitation.

    The received onset is where the cumulative energy of y first reaches ``fraction`` of the
    energy in the first quarter of the record after the excitation starts, refined back to
    where the smoothed envelope leaves the noise. Robust to 10-20 % noise; returns None when
    no arrival can be found.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    i_u = onset_index(u, 0.1)
    if i_u is None or len(y) < 8:
        return None
    seg = y[i_u:]
    # Noise floor from the quietest stretch right after the excitation starts; smoothing width
    # and that stretch scale with the record up to REFERENCE_SAMPLES (a longer record's first
    # 2 % would already hold the arrival).
    scale = min(len(seg), REFERENCE_SAMPLES)
    env = _moving_rms(seg, max(4, scale // 400))
    head = env[: max(8, scale // 50)]
    floor = float(np.median(head))
    peak = float(np.max(env))
    if peak <= 0 or peak < 3 * floor:
        return None
    level = floor + fraction * (peak - floor)
    above = np.nonzero(env > level)[0]
    if above.size == 0:
        return None
    return float(t[i_u + above[0]] - t[i_u])


def _moving_rms(x: np.ndarray, width: int) -> np.ndarray:
    return np.sqrt(np.maximum(moving_average(x * x, width), 0.0))
