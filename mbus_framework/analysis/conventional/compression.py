"""Cyclic compression test (Section 6.2.3.2): stiffness, damping, E and eta from one record.

The specimen is the spring-damper of eq. 6.14, ``b dx/dt + k x = u``: a displacement
``x = A_x cos(w t)`` needs the force ``u = A_u cos(w t + phi)`` (eq. 6.16), with
``|G| = A_x / A_u = 1 / sqrt(w^2 b^2 + k^2)`` and ``tan(phi) = w b / k`` (eqs. 6.17-6.21), so

    k = cos(phi) / |G|   [N/m],      b = sin(phi) / (w |G|)   [N s/m],
    E = (l / A) k        [Pa],       eta = (l / A) b          [Pa s]      (eqs. 6.22, 6.23)

with l the specimen length and A its loaded area. In complex amplitudes (phasors, ``x(t) =
Re(X exp(i w t))``) this is simply ``k + i w b = U / X``.

Each channel is fitted by linear least squares (statsmodels OLS) at the known test frequency,

    y(t) = p_0 + p_1 s + ... + p_d s^d + a cos(w t) + c sin(w t),   phasor a - i c,

where the polynomial in the scaled time s removes the preload offset and slow drift
(relaxation, creep). Standard errors of k and b propagate the two fits' covariances
(independent channels, white residuals) through ``U / X`` to first order (delta method); the
geometry l, A is taken as exact. Using several cycles averages the noise down.

A record is rejected with one line naming the file when it is not a clean sinusoid at the
stated frequency: too few cycles or samples per cycle, a channel whose variance (after drift
removal) the sinusoid explains less than ``min_explained`` of (the message gives the dominant
frequency found instead), or a force that lags the displacement (negative k or significantly
negative b: swapped or sign-reversed channels).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.analysis.conventional.columns import Quantity, read_export

#: Columns of a compression record (headers may carry units, e.g. ``force [g]``).
RECORD_COLUMNS = (
    Quantity("time", ("time", "t"), "time"),
    Quantity("force", ("force", "load", "u"), "force"),
    Quantity("displacement", ("displacement", "position", "distance", "deformation", "x"), "length"),
)


@dataclass(frozen=True)
class SinusoidFit:
    """Least-squares fit ``drift(t) + a cos(w t) + c sin(w t)`` of one channel.

    ``phasor = a - i c`` (so the sinusoid is ``Re(phasor exp(i w t))``), ``cov`` the 2x2
    covariance of (a, c), ``explained`` the fraction of the drift-free variance the sinusoid
    explains, ``residual_std`` the standard deviation of the residuals.
    """

    a: float
    c: float
    cov: np.ndarray
    explained: float
    residual_std: float

    @property
    def phasor(self) -> complex:
        return complex(self.a, -self.c)

    @property
    def amplitude(self) -> float:
        return abs(self.phasor)


def fit_sinusoid(t: np.ndarray, y: np.ndarray, omega: float, drift_degree: int = 1) -> SinusoidFit:
    """Fit one channel at the known angular frequency ``omega`` [rad/s] (statsmodels OLS)."""
    import statsmodels.api as sm

    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    t0 = t - t[0]
    span = t0[-1] if t0[-1] > 0 else 1.0
    s = 2.0 * t0 / span - 1.0  # drift polynomial on [-1, 1] for conditioning
    drift = np.vander(s, drift_degree + 1, increasing=True)
    design = np.column_stack([drift, np.cos(omega * t0), np.sin(omega * t0)])
    full = sm.OLS(y, design).fit()
    baseline = sm.OLS(y, drift).fit()
    cov = np.asarray(full.cov_params())[-2:, -2:]
    flat = baseline.ssr <= y.size * (1e-12 * max(float(np.abs(y).max()), np.finfo(float).tiny)) ** 2
    explained = float("nan") if flat else 1.0 - full.ssr / baseline.ssr
    resid_std = float(np.sqrt(full.ssr / max(full.df_resid, 1.0)))
    return SinusoidFit(float(full.params[-2]), float(full.params[-1]), cov, float(explained), resid_std)


@dataclass(frozen=True)
class CompressionResult:
    """One cyclic compression record reduced to k, b, E, eta (SI) with standard errors."""

    source: str
    frequency: float
    cycles: float
    gain: float
    phase: float
    k: float
    k_se: float
    b: float
    b_se: float
    E: float
    E_se: float
    eta: float
    eta_se: float
    explained_force: float
    explained_displacement: float

    def as_dict(self) -> dict:
        return asdict(self)


def stiffness_damping(force: SinusoidFit, displacement: SinusoidFit, omega: float):
    """(k, b, cov[(k, b)]) from the two channel fits: ``k + i w b = U / X`` and the delta method."""
    U, X = force.phasor, displacement.phasor
    Z = U / X
    # dZ / d(a_x, c_x, a_u, c_u) with X = a_x - i c_x, U = a_u - i c_u
    dZ = np.array([-Z / X, 1j * Z / X, 1.0 / X, -1j / X])
    jac = np.vstack([dZ.real, dZ.imag / omega])
    cov_in = np.zeros((4, 4))
    cov_in[:2, :2] = displacement.cov
    cov_in[2:, 2:] = force.cov
    return float(Z.real), float(Z.imag / omega), jac @ cov_in @ jac.T


def _dominant_frequency(t: np.ndarray, y: np.ndarray) -> float:
    from scipy.signal import periodogram

    fs = 1.0 / float(np.median(np.diff(t)))
    f, p = periodogram(y - np.polyval(np.polyfit(t - t[0], y, 1), t - t[0]), fs=fs, detrend=False)
    return float(f[1:][np.argmax(p[1:])]) if f.size > 1 else float("nan")


def analyse_compression(t, force, displacement, *, frequency: float, length: float, area: float,
                        drift_degree: int = 1, min_explained: float = 0.95, min_cycles: float = 2.0,
                        source: str = "<record>") -> CompressionResult:
    """k, b, E, eta of one record (SI arrays) at the stated test ``frequency`` [Hz].

    ``length`` [m] and ``area`` [m^2] are the specimen's; see the module docstring for the
    equations, the fit and the checks that raise :class:`DataError`.
    """
    t = np.asarray(t, dtype=float)
    force = np.asarray(force, dtype=float)
    displacement = np.asarray(displacement, dtype=float)
    if not (frequency > 0 and length > 0 and area > 0):
        raise DataError(f"{source}: frequency, specimen length and area must be positive "
                        f"(got {frequency}, {length}, {area})")
    n_min = 4 * (drift_degree + 3)
    if t.size < n_min:
        raise DataError(f"{source}: {t.size} samples; a sinusoid fit needs at least {n_min}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        row = int(np.flatnonzero(steps <= 0)[0]) + 2
        raise DataError(f"{source}: time does not increase at data row {row}")
    cycles = float((t[-1] - t[0]) * frequency)
    if cycles < min_cycles:
        raise DataError(f"{source}: the record covers {cycles:.2f} cycles of {frequency:g} Hz; "
                        f"need at least {min_cycles:g}")
    per_cycle = 1.0 / (float(np.median(steps)) * frequency)
    if per_cycle < 4.0:
        raise DataError(f"{source}: {per_cycle:.1f} samples per cycle of {frequency:g} Hz; need at least 4")
    omega = 2.0 * math.pi * frequency
    fits = {}
    for name, y in (("force", force), ("displacement", displacement)):
        fit = fit_sinusoid(t, y, omega, drift_degree)
        if not np.isfinite(fit.explained):
            raise DataError(f"{source}: the {name} channel does not oscillate (constant after drift removal)")
        if fit.explained < min_explained:
            raise DataError(
                f"{source}: not a clean {frequency:g} Hz sinusoid: it explains {100 * fit.explained:.1f} % of "
                f"the {name} variance after drift removal (need {100 * min_explained:.0f} %); "
                f"dominant frequency {_dominant_frequency(t, y):.3g} Hz")
        fits[name] = fit
    k, b, cov = stiffness_damping(fits["force"], fits["displacement"], omega)
    k_se, b_se = (float(np.sqrt(max(v, 0.0))) for v in np.diag(cov))
    phase = math.atan2(b * omega, k)
    if k <= 0:
        raise DataError(f"{source}: force and displacement are out of phase by {math.degrees(phase):.1f} deg "
                        "(negative stiffness): are the channels swapped or a sign reversed?")
    if b < 0 and b < -3.0 * b_se:
        raise DataError(f"{source}: the force lags the displacement by {-math.degrees(phase):.2f} deg "
                        f"(negative damping, {-b / b_se:.1f} standard errors): channels swapped?")
    shape = length / area
    gain = fits["displacement"].amplitude / fits["force"].amplitude
    return CompressionResult(
        source=source, frequency=float(frequency), cycles=cycles, gain=float(gain), phase=float(phase),
        k=k, k_se=k_se, b=b, b_se=b_se, E=shape * k, E_se=shape * k_se, eta=shape * b, eta_se=shape * b_se,
        explained_force=fits["force"].explained, explained_displacement=fits["displacement"].explained)


def read_compression(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time [s], force [N], displacement [m]) of a record file; headers may carry units."""
    columns = read_export(path, RECORD_COLUMNS)
    return columns["time"], columns["force"], columns["displacement"]


def analyse_compression_file(path: str | Path, *, frequency: float, length: float, area: float,
                             **options) -> CompressionResult:
    """:func:`analyse_compression` of a record file (CSV/TSV, optionally gzipped)."""
    t, force, displacement = read_compression(path)
    return analyse_compression(t, force, displacement, frequency=frequency, length=length, area=area,
                               source=str(path), **options)
