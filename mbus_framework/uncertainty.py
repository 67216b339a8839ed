"""Parameter uncertainty from the Jacobian at the optimum (linearised least squares).

With residual variance s^2 = 2 cost / (N - p) and J = d yhat / d theta (free columns),

    Cov(theta) = s^2 (J^T J)^-1,   SE_i = sqrt(Cov_ii),   corr_ij = Cov_ij / (SE_i SE_j)

95 % intervals use Student's t with N - p degrees of freedom. Property intervals follow by
the delta method, Cov(P) = G Cov(theta) G^T with G = dP/dtheta (central differences).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats


@dataclass
class Uncertainty:
    names: list[str]
    covariance: np.ndarray
    standard_errors: np.ndarray
    correlation: np.ndarray
    dof: int
    residual_std: float

    def relative_standard_errors(self, values: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.standard_errors / np.abs(values)

    def intervals(self, values: np.ndarray, level: float = 0.95) -> np.ndarray:
        q = stats.t.ppf(0.5 + level / 2, max(self.dof, 1))
        return np.column_stack([values - q * self.standard_errors, values + q * self.standard_errors])


def from_jacobian(names: list[str], jacobian: np.ndarray, cost: float, scale: float | None = None) -> Uncertainty:
    """Linearised covariance of the free parameters (``scale`` = known noise variance, else s^2)."""
    J = np.asarray(jacobian, dtype=float)
    n, p = J.shape
    dof = max(n - p, 1)
    s2 = scale if scale is not None else 2.0 * cost / dof
    # Column scaling keeps the inversion well conditioned for parameters of mixed magnitude.
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms
    cov_s = s2 * np.linalg.pinv(Js.T @ Js)
    cov = cov_s / np.outer(norms, norms)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(se, se)
    corr[~np.isfinite(corr)] = 0.0
    return Uncertainty(list(names), cov, se, corr, dof, float(np.sqrt(s2)))


def property_covariance(to_properties, theta: np.ndarray, free: np.ndarray, cov_free: np.ndarray):
    """Delta-method covariance of the material properties; returns (names, values, cov)."""
    base = to_properties(theta)
    names = list(base)
    values = np.array([base[k] for k in names])
    idx = np.flatnonzero(free)
    G = np.zeros((len(names), idx.size))
    for j, i in enumerate(idx):
        h = 1e-6 * abs(theta[i]) or 1e-12
        up, dn = theta.copy(), theta.copy()
        up[i] += h
        dn[i] -= h
        pu, pd = to_properties(up), to_properties(dn)
        G[:, j] = [(pu[k] - pd[k]) / (2 * h) for k in names]
    return names, values, G @ cov_free @ G.T
