"""Moving average in O(N) time whatever its width (long records: a width that grows with the
record made ``np.convolve`` quadratic)."""
from __future__ import annotations

import numpy as np


def moving_average(x: np.ndarray, width: int) -> np.ndarray:
    """``np.convolve(x, np.ones(width) / width, mode="same")`` (for width <= len(x)) by a running sum:

        out[i] = (1/w) sum_{k=i+c-w+1}^{i+c} x[k],   c = (w - 1) // 2,  x = 0 outside the record.

    The running sum is accumulated in float64 relative to the mean, so round-off is
    eps x the record's total (the box-filtered values are meant for thresholds and peaks)."""
    x = np.asarray(x, dtype=float)
    w = int(width)
    if w < 1:
        raise ValueError(f"width must be >= 1, not {width}")
    n = x.size
    if w == 1 or n == 0:
        return x.copy()
    c = (w - 1) // 2
    csum = np.concatenate([[0.0], np.cumsum(x)])
    i = np.arange(n)
    hi = np.minimum(i + c + 1, n)
    lo = np.clip(i + c - w + 1, 0, n)
    return (csum[hi] - csum[lo]) / w
