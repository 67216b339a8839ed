"""Straight-line calibration: y = a + b x by least squares, its bands and its inverse.

The fit is statsmodels OLS (t-tests of slope and intercept, their intervals) and
scipy.stats.pearsonr (r and its p-value). With n points, s the residual standard deviation
(n - 2 degrees of freedom), x_bar the mean and S_xx the sum of squared deviations of x, and t
the two-sided Student-t quantile at the chosen level:

    confidence band (the mean line):   a + b x  +-  t s sqrt(1/n + (x - x_bar)^2 / S_xx)
    prediction band (a new point):     a + b x  +-  t s sqrt(1 + 1/n + (x - x_bar)^2 / S_xx)

Inverse prediction (the calibration problem): a new y0 (the mean of m new measurements) gives
x0 = x_bar + (y0 - a - b x_bar) / b, and its interval is every x whose prediction interval
contains y0 (Fieller), the roots of

    (b^2 - t^2 s^2 / S_xx) d^2 - 2 b e d + e^2 - t^2 s^2 (1/m + 1/n) = 0,   d = x - x_bar,
    e = y0 - a - b x_bar.

It is finite only when the slope differs from zero at the chosen level (b^2 S_xx > t^2 s^2);
otherwise the interval is (-inf, inf).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from mbus_framework.errors import DataError


@dataclass(frozen=True)
class LineFit:
    """Ordinary least-squares line y = intercept + slope x with its statistics."""

    n: int
    slope: float
    intercept: float
    slope_se: float
    intercept_se: float
    slope_t: float
    intercept_t: float
    slope_p: float
    intercept_p: float
    slope_ci_low: float
    slope_ci_high: float
    intercept_ci_low: float
    intercept_ci_high: float
    r: float
    r_p: float
    residual_std: float
    df: int
    x_mean: float
    sxx: float
    x_min: float
    x_max: float
    y_min: float
    y_max: float
    level: float = 0.95

    @property
    def t(self) -> float:
        """Two-sided Student-t quantile at ``level`` with ``df`` degrees of freedom."""
        from scipy import stats

        return float(stats.t.ppf(0.5 + self.level / 2.0, self.df))

    def predict(self, x) -> np.ndarray:
        return self.intercept + self.slope * np.asarray(x, dtype=float)

    def bands(self, x) -> dict[str, np.ndarray]:
        """Mean line, confidence band and prediction band at ``x`` (see module docstring)."""
        x = np.asarray(x, dtype=float)
        mean = self.predict(x)
        lever = 1.0 / self.n + (x - self.x_mean) ** 2 / self.sxx
        ci = self.t * self.residual_std * np.sqrt(lever)
        pi = self.t * self.residual_std * np.sqrt(1.0 + lever)
        return {"mean": mean, "ci_low": mean - ci, "ci_high": mean + ci, "pi_low": mean - pi, "pi_high": mean + pi}

    def inverse(self, y0, m: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x0, low, high) for new y0 values, each the mean of ``m`` measurements (Fieller)."""
        y0 = np.asarray(y0, dtype=float)
        b, ts2 = self.slope, (self.t * self.residual_std) ** 2
        e = y0 - self.intercept - b * self.x_mean
        x0 = self.x_mean + e / b
        A = b * b - ts2 / self.sxx
        if A <= 0:
            inf = np.full_like(y0, np.inf)
            return x0, -inf, inf
        root = np.sqrt(e * e * ts2 / self.sxx + A * ts2 * (1.0 / m + 1.0 / self.n))
        d1, d2 = (b * e - root) / A, (b * e + root) / A
        return x0, self.x_mean + np.minimum(d1, d2), self.x_mean + np.maximum(d1, d2)

    @property
    def finite_inverse(self) -> bool:
        """Whether inverse intervals are finite (the slope is significant at ``level``)."""
        return self.slope ** 2 * self.sxx > (self.t * self.residual_std) ** 2

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict, where: str = "<calibration>") -> "LineFit":
        names = {f.name for f in fields(cls)}
        missing = sorted(names - set(data) - {"level"})
        if missing:
            raise DataError(f"{where}: missing {', '.join(missing)}")
        return cls(**{k: data[k] for k in names if k in data})


def fit_line(x, y, level: float = 0.95, where: str = "<data>") -> LineFit:
    """Fit y = a + b x (statsmodels OLS, scipy.stats.pearsonr); needs 3+ points and varying x."""
    import statsmodels.api as sm
    from scipy import stats

    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.size < 3:
        raise DataError(f"{where}: {x.size} usable samples; a regression needs at least 3")
    if np.ptp(x) == 0 or np.ptp(y) == 0:
        which = "conventional" if np.ptp(x) == 0 else "MBUS"
        raise DataError(f"{where}: the {which} values do not vary; no regression possible")
    res = sm.OLS(y, sm.add_constant(x)).fit()
    ci = np.asarray(res.conf_int(alpha=1.0 - level))
    r, r_p = stats.pearsonr(x, y)
    return LineFit(
        n=int(x.size), slope=float(res.params[1]), intercept=float(res.params[0]),
        slope_se=float(res.bse[1]), intercept_se=float(res.bse[0]),
        slope_t=float(res.tvalues[1]), intercept_t=float(res.tvalues[0]),
        slope_p=float(res.pvalues[1]), intercept_p=float(res.pvalues[0]),
        slope_ci_low=float(ci[1, 0]), slope_ci_high=float(ci[1, 1]),
        intercept_ci_low=float(ci[0, 0]), intercept_ci_high=float(ci[0, 1]),
        r=float(r), r_p=float(r_p), residual_std=float(math.sqrt(res.ssr / res.df_resid)), df=int(res.df_resid),
        x_mean=float(x.mean()), sxx=float(((x - x.mean()) ** 2).sum()),
        x_min=float(x.min()), x_max=float(x.max()), y_min=float(y.min()), y_max=float(y.max()), level=float(level))
