"""Parameter uncertainty from the Jacobian at the optimum (linearised least squares).

With residual variance s^2 = 2 cost / (N - p) and J = d yhat / d theta (free columns),

    Cov(theta) = s^2 (J^T J)^-1,   SE_i = sqrt(Cov_ii),   corr_ij = Cov_ij / (SE_i SE_j)

(J^T J)^-1 comes from an SVD of the column-scaled J with no cut-off: a direction the data
cannot see gives a huge (or infinite) variance instead of being dropped, so an unidentifiable
parameter never looks precise. ``condition`` is the smallest/largest singular value ratio.

95 % intervals use Student's t with N - p degrees of freedom. Property intervals follow by
the delta method, Cov(P) = G Cov(theta) G^T with G = dP/dtheta (central differences).

A positive quantity v (a ``log_scale`` parameter, a positive property) gets its interval on the
log scale, SE(ln v) = SE(v) / v:  [v exp(-q SE/v), v exp(+q SE/v)], never reaching zero (a lower
end that underflows, e.g. an infinite SE, is stored as the smallest normal float); others get
v -+ q SE.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special


@dataclass
class Uncertainty:
    names: list[str]
    covariance: np.ndarray
    standard_errors: np.ndarray
    correlation: np.ndarray
    dof: int
    residual_std: float
    condition: float = 1.0

    def relative_standard_errors(self, values: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.standard_errors / np.abs(values)

    def intervals(self, values: np.ndarray, level: float = 0.95, positive=None) -> np.ndarray:
        """(n, 2) intervals; ``positive``: mask of the quantities taken on the log scale."""
        q = special.stdtrit(max(self.dof, 1), 0.5 + level / 2)  # Student-t quantile
        return confidence_intervals(values, self.standard_errors, q, positive)


def confidence_intervals(values, standard_errors, q: float, positive=None) -> np.ndarray:
    """(n, 2) intervals v -+ q SE, or v exp(-+q SE / v) where ``positive`` (and v > 0)."""
    v = np.atleast_1d(np.asarray(values, dtype=float))
    se = np.atleast_1d(np.asarray(standard_errors, dtype=float))
    out = np.column_stack([v - q * se, v + q * se])
    log = np.zeros(v.shape, bool) if positive is None else np.asarray(positive, bool) & (v > 0)
    if log.any():
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            z = q * se[log] / v[log]
            lo = np.maximum(v[log] * np.exp(-z), np.finfo(float).tiny)
            hi = v[log] * np.exp(z)
        lo[np.isnan(z)], hi[np.isnan(z)] = np.nan, np.nan
        out[log] = np.column_stack([lo, hi])
    return out


def positive_interval(value: float, standard_error: float, q: float) -> list[float]:
    """[lo, hi] of one positive quantity on the log scale (see :func:`confidence_intervals`)."""
    return [float(x) for x in confidence_intervals([value], [standard_error], q, [True])[0]]


def from_jacobian(
    names: list[str],
    jacobian: np.ndarray,
    cost: float,
    scale: float | None = None,
    noise_filter=None,
    dt: float | None = None,
) -> Uncertainty:
    """Linearised covariance of the free parameters.

    ``scale``: the known variance of the white noise, else estimated from the residuals.
    ``noise_filter``: the linear map F a compensator applied to the record (its noise is
    sigma F e, e white); then Cov = sigma^2 A (F^T J)^T (F^T J) A, A = (J^T J)^-1 (sandwich),
    and sigma^2 = ||r||^2 / (tr(F^T F) - p) when not known.
    """
    J = np.asarray(jacobian, dtype=float)
    n, p = J.shape
    dof = max(n - p, 1)
    A, condition = scaled_inverse_gram(J)
    if noise_filter is None:
        s2 = scale if scale is not None else 2.0 * cost / dof
        cov = s2 * A
    else:
        s2 = scale if scale is not None else 2.0 * cost / max(filter_power(noise_filter, n, dt) - p, 1.0)
        FtJ = noise_filter.adjoint(J, dt)
        with np.errstate(invalid="ignore"):
            cov = s2 * A @ (FtJ.T @ FtJ) @ A
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(se, se)
    corr[~np.isfinite(corr)] = 0.0
    np.fill_diagonal(corr, 1.0)
    return Uncertainty(list(names), cov, se, corr, dof, float(np.sqrt(s2)), condition)


def filter_power(noise_filter, n: int, dt: float, probes: int = 4) -> float:
    """tr(F^T F) of a linear filter on n samples (Hutchinson: E||F z||^2 over z ~ N(0, I))."""
    rng = np.random.default_rng(12345)
    z = rng.standard_normal((n, probes))
    Fz = noise_filter(z, dt)
    return float(np.sum(Fz**2) / probes)


def scaled_inverse_gram(J: np.ndarray) -> tuple[np.ndarray, float]:
    """(J^T J)^-1 by an SVD of J with unit-norm columns, no truncation; and the condition
    (smallest/largest singular value). A zero singular value gives infinite variances for
    the parameters in that direction."""
    J = np.asarray(J, dtype=float)
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    _, sv, Vt = np.linalg.svd(J / norms, full_matrices=False)
    V = Vt.T
    # Singular values at round-off level are exact zeros: their directions are unseen.
    null = sv <= max(J.shape) * np.finfo(float).eps * (sv.max() if sv.size else 0.0)
    live = ~null
    cov = (V[:, live] / sv[live] ** 2) @ V[:, live].T
    if null.any():
        # parameters with a real (not round-off) component along an unseen direction
        along = (np.abs(V[:, null]) > 1e-8).any(axis=1)
        cov[along, :] = np.inf
        cov[:, along] = np.inf
        cov[np.ix_(along, along)] = np.where(np.eye(along.sum(), dtype=bool), np.inf, np.nan)
    cov = cov / np.outer(norms, norms)
    condition = float(sv.min() / sv.max()) if sv.size and sv.max() > 0 else 0.0
    return cov, condition


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
    with np.errstate(invalid="ignore"):  # an unseen direction (infinite variance) times a zero slope
        return names, values, G @ cov_free @ G.T
