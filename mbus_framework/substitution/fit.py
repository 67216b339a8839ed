"""Fit a material law to the in-band lines of a substitution record.

Residual per line (real and imaginary parts): r = (S - R T(w; p)^P) / |S|_rms, T from
:mod:`.plate` with M(w) from the law, parameters p = exp(x) fitted in log coordinates by
Levenberg-Marquardt (scipy ``least_squares``) from the law's start at the model-free modulus of
the band centre. Covariance of x: s^2 (J^T J)^-1 with s^2 = SSR / (2 F - n); intervals are
exp(x +- 1.96 se_x), so never negative. On real records the residual is mostly model mismatch,
and s^2 carries it into the intervals.

The explained in-band energy is 1 - sum |S - R T^P|^2 / sum |S|^2; the comparison with the
model-free measurement is :func:`checks`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from mbus_framework.engine.continuum_laws import Law, velocity_attenuation, wavenumber
from mbus_framework.substitution.model_free import NP_TO_DB_PER_CM, Dispersion
from mbus_framework.substitution.plate import substitution_ratio
from mbus_framework.substitution.spectra import Spectra
from mbus_framework.substitution.water import Water


@dataclass
class LawFit:
    law: Law
    values: np.ndarray
    log_covariance: np.ndarray
    w0: float
    rho: float
    explained: float  # fraction of in-band energy of the sample shot the model explains
    bic: float
    nfev: int
    status: str
    structure: dict = field(default_factory=dict)  # residual structure across lines (residual_structure)
    dispersion: Dispersion = field(repr=False, default=None)
    velocity_se: np.ndarray = field(repr=False, default=None)
    attenuation_se: np.ndarray = field(repr=False, default=None)

    @property
    def standard_errors(self) -> np.ndarray:
        return self.values * np.sqrt(np.diag(self.log_covariance))

    def intervals(self, z: float = 1.96) -> np.ndarray:
        se = np.sqrt(np.diag(self.log_covariance))
        return np.column_stack([self.values * np.exp(-z * se), self.values * np.exp(z * se)])


class SubstitutionProblem:
    """The lines, geometry and water of one record; ``predict`` gives S = R T^P."""

    def __init__(self, sp: Spectra, rho: float, h: float, water: Water, passes: int = 2, reverberations: bool = True):
        self.sp, self.rho, self.h, self.water = sp, rho, h, water
        self.passes, self.reverberations = passes, reverberations
        self.w0 = float(np.sum(sp.w * np.abs(sp.R) ** 2) / np.sum(np.abs(sp.R) ** 2))
        self.scale = float(np.sqrt(np.mean(np.abs(sp.S) ** 2)))

    def predict(self, law: Law, p: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
        w = self.sp.w if w is None else w
        if callable(getattr(law, "transmission", None)):  # a lumped chain (substitution.chains)
            return self.sp.R * law.transmission(w, p, self.rho, self.h, self.water) ** self.passes
        M = law.modulus(w, p, self.w0)
        return self.sp.R * substitution_ratio(M, w, self.rho, self.h, self.water, self.passes, self.reverberations)

    def residual(self, law: Law, x: np.ndarray) -> np.ndarray:
        d = (self.sp.S - self.predict(law, np.exp(x))) / self.scale
        return np.concatenate([d.real, d.imag])


def fit_law(problem: SubstitutionProblem, law: Law, reference: Dispersion) -> LawFit:
    """Fit ``law`` from the model-free modulus at the band centre (``reference``)."""
    w0 = problem.w0
    c0, a0 = reference.at(w0 / (2 * np.pi))
    k = w0 / c0 - 1j * a0 / NP_TO_DB_PER_CM
    M_ref = problem.rho * w0**2 / k**2
    lo, hi = (np.log([b[i] for b in law.bounds]) for i in (0, 1))
    x0 = np.clip(np.log(law.start(M_ref, w0)), lo + 1e-9, hi - 1e-9)
    sol = least_squares(lambda x: problem.residual(law, x), x0, bounds=(lo, hi), method="trf", x_scale=1.0)
    m, n = sol.fun.size, x0.size
    ssr = float(sol.fun @ sol.fun)
    s2 = ssr / max(m - n, 1)
    JTJ = sol.jac.T @ sol.jac
    cov = s2 * np.linalg.pinv(JTJ)
    energy = float(np.sum(np.abs(problem.sp.S) ** 2)) / problem.scale**2
    explained = 1.0 - ssr / energy
    bic = m * np.log(ssr / m) + n * np.log(m)
    values = np.exp(sol.x)
    out = LawFit(law, values, cov, w0, problem.rho, explained, float(bic), int(sol.nfev), str(sol.message),
                 residual_structure(sol.fun[: m // 2] + 1j * sol.fun[m // 2 :]))
    out.dispersion, out.velocity_se, out.attenuation_se = law_dispersion(law, sol.x, cov, w0, problem.rho, reference.f)
    return out


def residual_structure(d: np.ndarray, lags: int = 10) -> dict:
    """How structured the complex residual d_k is across neighbouring lines: autocorrelation
    r_j = Re sum d_k conj(d_{k+j}) / sum |d_k|^2 and the Ljung-Box statistic
    Q = F (F + 2) sum_{j<=lags} r_j^2 / (F - j), chi-square with ``lags`` degrees of freedom for
    a white residual (p near 0: the law leaves a systematic, frequency-dependent misfit)."""
    from scipy.special import chdtrc

    d = np.asarray(d, dtype=complex)
    F = d.size
    lags = max(1, min(lags, F // 4))
    power = float(np.sum(np.abs(d) ** 2)) or 1.0
    r = np.array([float(np.real(np.sum(d[:-j] * np.conj(d[j:])))) / power for j in range(1, lags + 1)])
    Q = float(F * (F + 2) * np.sum(r**2 / (F - np.arange(1, lags + 1))))
    return {"lag1_correlation": float(r[0]), "ljung_box_Q": Q, "lags": int(lags), "p_value": float(chdtrc(lags, Q))}


def law_dispersion(law: Law, x: np.ndarray, cov: np.ndarray, w0: float, rho: float, f: np.ndarray):
    """The law's c(f) and alpha(f) with delta-method standard errors from the log covariance."""

    def curves(xx):
        w = 2 * np.pi * f
        c, a = velocity_attenuation(wavenumber(law.modulus(w, np.exp(xx), w0), w, rho), w)
        return np.concatenate([c, a])

    base = curves(x)
    J = np.empty((base.size, x.size))
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = 1e-6
        J[:, i] = (curves(x + e) - curves(x - e)) / 2e-6
    se = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, cov, J), 0.0))
    n = f.size
    return Dispersion(f, base[:n], base[n:]), se[:n], se[n:]


#: The published check: frequencies [Hz] and tolerances against the model-free measurement.
VELOCITY_CHECK_HZ = (1.5e6, 2.0e6, 2.5e6, 3.0e6)
ATTENUATION_CHECK_HZ = (2.0e6, 2.5e6, 3.0e6)


def checks(fit: LawFit, reference: Dispersion) -> list[dict]:
    """Model against model-free at the check frequencies inside the band: phase velocity within
    1 %, attenuation within 20 % or 1.5 dB/cm (the larger)."""
    rows = []
    lo, hi = reference.f[0], reference.f[-1]
    for f0 in sorted(set(VELOCITY_CHECK_HZ) | set(ATTENUATION_CHECK_HZ)):
        if not lo <= f0 <= hi:
            continue
        c_m, a_m = fit.dispersion.at(f0)
        c_r, a_r = reference.at(f0)
        row = {"frequency_Hz": f0, "velocity_model": c_m, "velocity_model_free": c_r,
               "attenuation_model_dB_cm": a_m, "attenuation_model_free_dB_cm": a_r}
        if f0 in VELOCITY_CHECK_HZ:
            row["velocity_ok"] = bool(abs(c_m - c_r) <= 0.01 * abs(c_r))
        if f0 in ATTENUATION_CHECK_HZ:
            row["attenuation_ok"] = bool(abs(a_m - a_r) <= max(0.2 * abs(a_r), 1.5))
        rows.append(row)
    return rows
