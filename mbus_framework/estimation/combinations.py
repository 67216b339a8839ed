"""Which combinations of correlated parameters a record determines.

Correlation is the *shape* of the uncertainty, not its size: two parameters correlated at
r = 0.999 may each be known to 0.1 %. What the user can act on is, per group of correlated
parameters, the product of powers prod_i theta_i^a_i the record fixes best and the one it
fixes worst. In log space, with the relative covariance

    C_ij = Cov(theta_i, theta_j) / (theta_i theta_j)      (= Cov(ln theta_i, ln theta_j)),

the relative standard error of prod_i theta_i^a_i is sqrt(a^T C a). The eigenvector of C with
the smallest eigenvalue is the best-determined combination (for a pair trading off at r -> 1
with similar SEs, a ~ (1, -1): their ratio), the largest the worst (their product). Exponents
are scaled so the largest is 1 and rounded to two decimals; the standard error reported is
that of the rounded combination, so what is printed is what holds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Combination:
    """prod_i names_i ^ exponents_i and its relative standard error (a fraction)."""

    names: list[str]
    exponents: list[float]
    relative_se: float

    @property
    def expression(self) -> str:
        """``k_sigma/k_tau``, ``k_sigma*k_tau``, ``k_sigma*b_tau^0.52/k_tau`` ..."""
        num = [_power(n, a) for n, a in zip(self.names, self.exponents) if a > 0]
        den = [_power(n, -a) for n, a in zip(self.names, self.exponents) if a < 0]
        top = "*".join(num) if num else "1"
        if not den:
            return top
        return top + "/" + (den[0] if len(den) == 1 else "(" + "*".join(den) + ")")

    def as_dict(self) -> dict:
        return {"expression": self.expression, "exponents": dict(zip(self.names, self.exponents)),
                "relative_standard_error": self.relative_se}


def _power(name: str, a: float) -> str:
    return name if abs(a - 1.0) < 1e-9 else f"{name}^{a:g}"


def log_covariance(values: np.ndarray, covariance: np.ndarray) -> np.ndarray | None:
    """C_ij = Cov_ij / (theta_i theta_j); None unless every value is positive and finite."""
    v = np.asarray(values, dtype=float)
    if not (np.all(np.isfinite(v)) and np.all(v > 0) and np.all(np.isfinite(covariance))):
        return None
    return np.asarray(covariance, dtype=float) / np.outer(v, v)


def extreme_combinations(names: list[str], values: np.ndarray,
                         covariance: np.ndarray) -> tuple[Combination, Combination] | None:
    """(best, worst) determined power products of ``names`` (module docstring); None when a
    value is not positive (no log space) or the covariance is not finite."""
    C = log_covariance(values, covariance)
    if C is None:
        return None
    C = 0.5 * (C + C.T)
    _, vecs = np.linalg.eigh(C)
    return _rounded(names, vecs[:, 0], C), _rounded(names, vecs[:, -1], C)


def _rounded(names: list[str], vec: np.ndarray, C: np.ndarray) -> Combination:
    a = vec / vec[np.argmax(np.abs(vec))]
    a = np.round(a, 2)
    keep = a != 0
    se = float(np.sqrt(max(a @ C @ a, 0.0)))
    return Combination([n for n, k in zip(names, keep) if k], [float(x) for x in a[keep]], se)
