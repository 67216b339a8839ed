"""The joint fit: start from the per-record fits, local Levenberg-Marquardt, covariance, agreement.

* Noise levels: sigma_r^2 = 2 cost_r / (N_r - p_r) from record r's own fit (p_r free parameters).
* Start: a shared property is the precision-weighted mean of the per-record estimates,
  P_s = sum_r P_s,r / SE_r^2 / sum_r 1 / SE_r^2; per-record values start at their own fit.
* Local fit: ``scipy.optimize.least_squares(method="lm")`` in z = ln phi (properties, gains)
  and z = tau / h (delays), with the exact block Jacobian of :class:`JointProblem`.
* Covariance: with the sigma_r known, Cov(phi) = (J_w^T J_w)^-1 (J_w the weighted Jacobian).
* Agreement (likelihood ratio of the shared-parameter hypothesis): with chi2_r = ||w_r||^2,

      LR = sum_r chi2_r(joint) - sum_r chi2_r(own fit) ~ chi^2 with df = (R - 1) n_shared,

  p = Q(LR | df) (:func:`scipy.special.chdtrc`); p < 0.01 says the records do not share the material.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.special import chdtrc

from mbus_framework.estimation.uncertainty import Uncertainty, from_jacobian
from mbus_framework.joint.problem import JointProblem

AGREEMENT_LEVEL = 0.01


@dataclass
class JointFit:
    """The joint estimate phi with its covariance and the optimiser's report."""

    phi: np.ndarray
    cost: float
    uncertainty: Uncertainty
    residuals: list[np.ndarray]  # weighted, per record
    success: bool
    status: int
    message: str
    nfev: int
    njev: int


@dataclass(frozen=True)
class Agreement:
    """Likelihood-ratio test of the shared-parameter hypothesis."""

    statistic: float
    df: int
    p_value: float
    level: float = AGREEMENT_LEVEL

    @property
    def agree(self) -> bool:
        return self.p_value >= self.level

    def as_dict(self) -> dict:
        return {"test": "likelihood ratio: sum of per-record chi-square minima vs the joint fit",
                "statistic": self.statistic, "df": self.df, "p_value": self.p_value, "level": self.level,
                "agree": self.agree}


def noise_level(cost: float, n_samples: int, n_free: int) -> float:
    """sigma = sqrt(2 cost / (N - p))."""
    return float(np.sqrt(2.0 * cost / max(n_samples - n_free, 1)))


def precision_weighted(values: np.ndarray, std_errors: np.ndarray) -> float:
    """sum v / se^2 / sum 1 / se^2; the plain mean when no standard error is usable."""
    values, se = np.asarray(values, float), np.asarray(std_errors, float)
    ok = np.isfinite(se) & (se > 0)
    if not ok.any():
        return float(np.mean(values))
    w = 1.0 / se[ok] ** 2
    return float(np.sum(w * values[ok]) / np.sum(w))


class _Coordinates:
    """z = ln phi for positive slots, z = phi / unit for delays (unit: the record's sample interval)."""

    def __init__(self, jp: JointProblem):
        self.log = np.array([s.log_scale for s in jp.slots])
        self.unit = np.array([1.0 if s.log_scale else jp.problems[s.record].dt for s in jp.slots])
        self.lo, self.hi = jp.bounds()

    def z(self, phi: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.log(np.maximum(np.where(self.log, phi, 1.0), 1e-300)), phi / self.unit)

    def phi(self, z: np.ndarray) -> np.ndarray:
        phi = np.where(self.log, np.exp(np.where(self.log, z, 0.0)), z * self.unit)
        return np.clip(phi, self.lo, self.hi)

    def dphi_dz(self, phi: np.ndarray) -> np.ndarray:
        return np.where(self.log, phi, self.unit)


def fit_joint(jp: JointProblem, phi0: np.ndarray, max_nfev: int = 200, xtol: float = 1e-10,
              ftol: float = 1e-12) -> JointFit:
    """Local LM from ``phi0`` (the per-record fits' combination) with the exact joint Jacobian."""
    coords = _Coordinates(jp)

    def fun(z):
        with np.errstate(over="ignore", invalid="ignore"):
            w = np.concatenate(jp.weighted_residuals(coords.phi(z)))
        return np.where(np.isfinite(w), -w, 1e6)

    def jac(z):
        phi = coords.phi(z)
        with np.errstate(over="ignore", invalid="ignore"):
            _, J = jp.residuals_and_jacobian(phi)
        Jz = J * coords.dphi_dz(phi)
        return np.where(np.isfinite(Jz), Jz, 0.0)

    res = least_squares(fun, coords.z(np.asarray(phi0, float)), jac=jac, method="lm", x_scale=1.0,
                        xtol=xtol, ftol=ftol, max_nfev=max_nfev)
    phi = coords.phi(res.x)
    w, J = jp.residuals_and_jacobian(phi)
    cost = 0.5 * float(w @ w)
    unc = from_jacobian(jp.names, J, cost, scale=1.0)
    sizes = np.cumsum([p.y.size for p in jp.problems])[:-1]
    return JointFit(phi, cost, unc, np.split(w, sizes), bool(res.status > 0), int(res.status), str(res.message),
                    int(res.nfev), int(res.njev or 0))


def agreement(joint: JointFit, single_chi2: list[float], n_shared: int) -> Agreement:
    """LR = sum chi2(joint) - sum chi2(own fits), df = (R - 1) n_shared; p = chdtrc(df, LR)."""
    R = len(single_chi2)
    df = (R - 1) * n_shared
    stat = max(float(sum(float(w @ w) for w in joint.residuals) - sum(single_chi2)), 0.0)
    p = float(chdtrc(df, stat)) if df > 0 else 1.0
    return Agreement(stat, df, p)
