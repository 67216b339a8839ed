"""Whether two minima are one, and a search region around a start: the strategy's small geometry.

Parameters are compared in ln theta (log-scale, positive entries): two points are near when
|ln(a_i / b_i)| <= rtol for every such entry."""
from __future__ import annotations

import numpy as np

from mbus_framework.estimation.problem import FitProblem


def region_around(problem: FitProblem, theta0: np.ndarray, factor: float, lo: np.ndarray, hi: np.ndarray):
    """Bounds confining log-scale parameters to theta0 x/÷ factor (within lo, hi)."""
    lo, hi = lo.copy(), hi.copy()
    for i, p in enumerate(problem.parameters):
        if p.log_scale and theta0[i] > 0:
            lo[i] = max(lo[i], theta0[i] / factor)
            hi[i] = min(hi[i], theta0[i] * factor)
    return lo, hi


def near(a: np.ndarray, b: np.ndarray, rtol: float = 0.02) -> bool:
    """|ln(a_i / b_i)| <= rtol at every entry positive in both."""
    pos = (a > 0) & (b > 0)
    return bool(np.all(np.abs(np.log(a[pos] / b[pos])) <= rtol))
