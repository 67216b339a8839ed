"""Agreement of predicted with measured scores, and comparisons of two predictors
(Section 7.2.6; Kleinbaum et al. 2008).

* :func:`agreement`: Pearson r and its test; the straight line predicted = a + b measured
  (ordinary least squares, statsmodels) with t tests of b = 1 and a = 0 (the 45-degree line);
  RMSE, MAE and mean bias.
* :func:`fisher_z_test`: equality of two correlation coefficients from independent samples,
  z = (atanh r_1 - atanh r_2) / sqrt(1/(n_1 - 3) + 1/(n_2 - 3)) (the dissertation's test).
* :func:`dependent_correlation_test`: the same question when both predictors were scored on
  the *same* samples (Meng, Rosenthal and Rubin 1992), which accounts for the correlation
  r_12 between the two predictions.
* :func:`compare_lines`: parallelism (equal slopes) and equal intercepts of the two lines,
  t tests on the interaction and indicator terms of one OLS fit of the stacked data.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats


@dataclass(frozen=True)
class Agreement:
    n: int
    r: float
    r_p: float  # two-sided p of H0: rho = 0
    slope: float
    slope_se: float
    slope_t: float  # t of H0: slope = 1
    slope_p: float
    intercept: float
    intercept_se: float
    intercept_t: float  # t of H0: intercept = 0
    intercept_p: float
    rmse: float
    mae: float
    bias: float  # mean(predicted - measured)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def agreement(measured, predicted) -> Agreement:
    """r, slope and intercept of predicted = a + b measured, with their tests (see module)."""
    import statsmodels.api as sm

    x, y = np.asarray(measured, dtype=float), np.asarray(predicted, dtype=float)
    if x.shape != y.shape or x.size < 4:
        raise ValueError("agreement needs paired measured and predicted values, at least 4")
    r, r_p = stats.pearsonr(x, y)
    fit = sm.OLS(y, sm.add_constant(x)).fit()
    (a, b), (se_a, se_b) = fit.params, fit.bse
    dof = fit.df_resid
    t_b, t_a = (b - 1.0) / se_b, a / se_a
    err = y - x
    return Agreement(
        n=int(x.size), r=float(r), r_p=float(r_p),
        slope=float(b), slope_se=float(se_b), slope_t=float(t_b), slope_p=float(2 * stats.t.sf(abs(t_b), dof)),
        intercept=float(a), intercept_se=float(se_a), intercept_t=float(t_a), intercept_p=float(2 * stats.t.sf(abs(t_a), dof)),
        rmse=float(np.sqrt(np.mean(err**2))), mae=float(np.mean(np.abs(err))), bias=float(np.mean(err)),
    )


def fisher_z_test(r1: float, n1: int, r2: float, n2: int) -> dict[str, float]:
    """Two-sided test of rho_1 = rho_2 for correlations from independent samples."""
    if min(n1, n2) <= 3:
        raise ValueError("Fisher's Z test needs more than 3 samples per correlation")
    z = (np.arctanh(r1) - np.arctanh(r2)) / np.sqrt(1.0 / (n1 - 3) + 1.0 / (n2 - 3))
    return {"r1": float(r1), "r2": float(r2), "n1": int(n1), "n2": int(n2), "z": float(z), "p": float(2 * stats.norm.sf(abs(z)))}


def dependent_correlation_test(r1: float, r2: float, r12: float, n: int) -> dict[str, float]:
    """Meng, Rosenthal & Rubin (1992): rho(y, p_1) = rho(y, p_2) on the same n samples,
    with r12 = corr(p_1, p_2). Z = (z_1 - z_2) sqrt((n - 3) / (2 (1 - r12) h)),
    h = (1 - f rbar^2) / (1 - rbar^2), f = min(1, (1 - r12) / (2 (1 - rbar^2))),
    rbar^2 = (r1^2 + r2^2) / 2."""
    if n <= 3:
        raise ValueError("the test needs more than 3 samples")
    rbar2 = 0.5 * (r1**2 + r2**2)
    f = min(1.0, (1.0 - r12) / (2.0 * (1.0 - rbar2)))
    h = (1.0 - f * rbar2) / (1.0 - rbar2)
    if r12 >= 1.0:
        z = 0.0
    else:
        z = (np.arctanh(r1) - np.arctanh(r2)) * np.sqrt((n - 3) / (2.0 * (1.0 - r12) * h))
    return {"r1": float(r1), "r2": float(r2), "r12": float(r12), "n": int(n), "z": float(z), "p": float(2 * stats.norm.sf(abs(z)))}


def compare_lines(measured, predicted_1, predicted_2) -> dict[str, float]:
    """Parallelism and equal intercepts of predicted_k = a_k + b_k measured (k = 1, 2).

    One OLS fit of the stacked data, p = a_1 + b_1 x + (a_2 - a_1) D + (b_2 - b_1) D x with D
    the indicator of line 2: t tests of the D x term (parallelism) and the D term (intercepts),
    on the pooled residual variance with n_1 + n_2 - 4 degrees of freedom.
    """
    import statsmodels.api as sm

    x = np.asarray(measured, dtype=float)
    p1, p2 = np.asarray(predicted_1, dtype=float), np.asarray(predicted_2, dtype=float)
    xs = np.concatenate([x, x])
    d = np.concatenate([np.zeros_like(x), np.ones_like(x)])
    design = np.column_stack([np.ones_like(xs), xs, d, d * xs])
    fit = sm.OLS(np.concatenate([p1, p2]), design).fit()
    dof = fit.df_resid
    return {
        "slope_difference": float(fit.params[3]), "slope_t": float(fit.tvalues[3]),
        "slope_p": float(2 * stats.t.sf(abs(fit.tvalues[3]), dof)),
        "intercept_difference": float(fit.params[2]), "intercept_t": float(fit.tvalues[2]),
        "intercept_p": float(2 * stats.t.sf(abs(fit.tvalues[2]), dof)), "df": int(dof),
    }
