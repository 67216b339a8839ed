"""Local exploration in the time domain: the continuation and alignment tools of a local fit.

* :class:`BandFilter` - a zero-phase low-pass for band continuation: each local fit first
  matches a low-passed residual (few local minima), then the full record.
* :func:`align_time_scale` - a 1-D search over the time scale c (parameters times c**e, e
  their ``time_exponent``) that puts the model's arrival on the measured one, scored by the
  data energy a scaled model output explains.
* :func:`coordinate_scan` - a per-parameter log-grid scan of the same score.
* :func:`residual_autocorrelation` - the whiteness statistic of residuals.

The global search (:mod:`mbus_framework.estimation.global_search`) supplies the starts; these
tools serve the last-resort multi-start around the best minimum found
(:mod:`mbus_framework.estimation.strategy`).
"""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
from scipy import fft as sfft

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.estimation.problem import FitProblem


class BandFilter:
    """Zero-phase low-pass |H(f)| = 1 / sqrt(1 + (f/fc)^8) applied along axis 0 by FFT.

    The record is zero-padded to twice its length, so the filter is a linear convolution
    (no wrap-around). Being linear, it applies to residuals and Jacobians alike.
    """

    def __init__(self, cutoff_hz: float, n: int, dt: float):
        self.cutoff_hz = float(cutoff_hz)
        self.n = n
        self.nfft = sfft.next_fast_len(2 * n, real=True)
        f = sfft.rfftfreq(self.nfft, dt)
        self.gain = 1.0 / np.sqrt(1.0 + (f / cutoff_hz) ** 8)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        X = sfft.rfft(x, self.nfft, axis=0)
        g = self.gain if x.ndim == 1 else self.gain[:, None]
        return sfft.irfft(X * g, self.nfft, axis=0)[: self.n]


def signal_bandwidth(y: np.ndarray, dt: float, fraction: float = 0.99) -> float:
    """Frequency [Hz] below which ``fraction`` of the record's power lies."""
    Y = np.abs(np.fft.rfft(y - np.mean(y))) ** 2
    f = np.fft.rfftfreq(len(y), dt)
    cum = np.cumsum(Y)
    if cum[-1] <= 0:
        return float(f[-1])
    return float(f[min(np.searchsorted(cum, fraction * cum[-1]), len(f) - 1)])


def time_exponents(problem: "FitProblem") -> np.ndarray:
    return np.array([p.time_exponent for p in problem.parameters], dtype=float)


def align_time_scale(problem: "FitProblem", theta: np.ndarray, options, points: int | None = None):
    """Best time scale c for ``theta`` (free parameters scaled by c**e); returns (theta_c, c, nfev).

    Each grid point is scored by the residual after the best amplitude factor a:
    min_a ||a yhat - y||^2 = ||y||^2 - (yhat.y)^2 / ||yhat||^2.
    """
    e = time_exponents(problem) * problem.free
    if not np.any(e):
        return theta, 1.0, 0
    points = points or options.time_scale_points
    r = options.time_scale_range
    scales = np.exp(np.linspace(-np.log(r), np.log(r), points))
    lo, hi = problem.lower, problem.upper
    best, best_c, nfev = _explained_energy(problem, theta), 1.0, 1  # the start itself competes
    for c in scales:
        th = theta * c**e
        if np.any(th < lo) or np.any(th > hi):
            continue
        score = _explained_energy(problem, th)
        nfev += 1
        if score > best:
            best, best_c = score, float(c)
    return theta * best_c**e, best_c, nfev


def _explained_energy(problem: "FitProblem", theta: np.ndarray) -> float:
    """(yhat . y)^2 / ||yhat||^2: the data energy a scaled model output explains."""
    with np.errstate(over="ignore", invalid="ignore"):
        yhat = problem.predict(theta)
    denom = float(yhat @ yhat)
    if not np.isfinite(denom) or denom <= 0:
        return -np.inf
    return float(yhat @ problem.y) ** 2 / denom


def coordinate_scan(problem: "FitProblem", theta: np.ndarray, options, points: int = 16):
    """Per-parameter log-grid scan (x/÷ spread) keeping each best point; returns (theta, nfev)."""
    theta = theta.copy()
    nfev = 0
    factors = np.exp(np.linspace(-np.log(options.spread), np.log(options.spread), points))
    best = _explained_energy(problem, theta)
    for _ in range(options.coordinate_scan):
        for i in np.flatnonzero(problem.free):
            for f in factors:
                trial = theta.copy()
                trial[i] = theta[i] * f
                if not (problem.lower[i] <= trial[i] <= problem.upper[i]):
                    continue
                score = _explained_energy(problem, trial)
                nfev += 1
                if score > best:
                    best, theta = score, trial
    return theta, nfev


def residual_whiteness(problem: "FitProblem", theta: np.ndarray, lags: int = 10) -> float:
    """Mean |normalised autocorrelation| of the residual y - yhat at lags 1..``lags``.

    About 0.8/sqrt(N) for white noise; near 1 when a structured misfit is left (a local
    minimum of a wave model leaves a delayed or mistuned copy of the signal).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        r = problem.y - problem.predict(theta)
    if not np.all(np.isfinite(r)):
        return np.inf
    return residual_autocorrelation(r, lags)


def residual_autocorrelation(r: np.ndarray, lags: int = 10) -> float:
    """Mean |normalised autocorrelation| of residuals r at lags 1..``lags``."""
    r = np.asarray(r, dtype=float) - np.mean(r)
    denom = float(r @ r)
    if denom <= 0 or not np.isfinite(denom):
        return 0.0
    return float(np.mean([abs(r[:-k] @ r[k:]) / denom for k in range(1, lags + 1)]))


def record_windows(problem: "FitProblem", stages: int, shortest: int = 64) -> list[tuple[int, "FitProblem"]]:
    """Time continuation: the problem on the record's first N/2^k samples, k = stages..1
    (windows shorter than ``shortest`` samples are left out); empty when an output filter or a
    noise filter is tied to the whole record.

    A lightly damped chain rings on through the record, so a small error in a mode frequency
    grows into a phase error proportional to time: the cost basin of the full record is as
    narrow as 1/(f N dt) in relative frequency, that of a window 2^k times wider. Each window's
    minimum starts the next, twice as long.
    """
    if stages <= 0 or problem.output_filter is not None or problem.noise_filter is not None:
        return []
    n_all = len(problem.y)
    out = []
    for k in range(stages, 0, -1):
        n = n_all >> k
        if n >= shortest:
            out.append((n, dataclasses.replace(problem, t=problem.t[:n], u=problem.u[:n], y=problem.y[:n])))
    return out
