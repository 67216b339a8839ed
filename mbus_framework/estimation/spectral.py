"""The record seen in the frequency domain: what the global search and the frequency-domain
solver fit.

Transient records (:func:`record_spectrum`). A record y[k] = (g * u)[k], k < N, from rest has
discrete-time Fourier transforms Y(f) = sum_k y[k] e^{-i 2 pi f k h} that satisfy

    Y(f) ~= G(i 2 pi f) P(f) U(f),      P(f) = hold response (ZOH: e^{-i pi f h} sinc(f h))

up to the response still ringing when the record ends (leakage; small when the medium's
impulse response is short against the record). Y and U are taken on a *logarithmic* grid
f_i = f_lo e^{i step} over the band the input excites: a model running c = e^{j step} times
faster has G_c(f_i) = G(f_i / c) = G(f_{i-j}), so a whole time-scale scan is a shift along
the grid (:mod:`mbus_framework.estimation.global_search`). White output noise of variance
sigma^2 adds variance N sigma^2 to every Y(f_i).

Periodic records (:func:`periodic_lines`). With an input of period P samples (an integer) and
M >= 1 steady-state periods, the period-averaged DFT lines satisfy Y_k = H(z_k) U_k exactly,
H the ZOH-sampled response (:mod:`mbus_framework.engine.frequency`); with M >= 2 the scatter
of the periods gives the noise of every line and of the record, model-free.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from mbus_framework.engine.hold import hold_response
from mbus_framework.engine.moving import moving_average

#: Log step of the analysis grid: 3 % between lines (a time-scale resolution of 3 %).
DEFAULT_STEP = 0.03


def dtft(x: np.ndarray, f: np.ndarray, dt: float, chunk: int = 4096) -> np.ndarray:
    """X(f) = sum_k x[k] e^{-i 2 pi f k dt} at arbitrary frequencies (memory O(F chunk)); x (N,)
    or several records (R, N) at once (then (R, F)).

    The kernel of a chunk, e^{-i w (a B + b)} = e^{-i w a B} e^{-i w b} (B = 64), is built
    from 2 sqrt(chunk) exponentials per frequency instead of chunk."""
    x = np.asarray(x, dtype=float)
    f = np.asarray(f, dtype=float)
    rows = np.atleast_2d(x)
    n = rows.shape[1]
    width = min(chunk, n)
    B = 64
    nb = -(-width // B)
    w = -2j * np.pi * f * dt
    kernel = (np.exp(np.multiply.outer(w, np.arange(nb) * float(B)))[:, :, None]
              * np.exp(np.multiply.outer(w, np.arange(B)))[:, None, :]).reshape(f.size, nb * B)[:, :width]
    out = np.zeros((rows.shape[0], f.size), dtype=complex)
    for start in range(0, n, width):
        seg = rows[:, start : start + width]
        out += np.exp(w * start) * (seg @ kernel[:, : seg.shape[1]].T)
    return out if x.ndim > 1 else out[0]


def excited_band(u: np.ndarray, dt: float, floor: float = 1e-2) -> tuple[float, float]:
    """(f_lo, f_hi) [Hz]: where the smoothed input power is within ``floor`` of its peak.

    f_lo is at least 3 / record length (coarser frequencies are not resolved), f_hi at most
    0.4 / dt (below Nyquist, where the hold and aliasing still leave the model exact enough).
    """
    u = np.asarray(u, dtype=float)
    n = u.size
    P = np.abs(np.fft.rfft(u - u.mean())) ** 2
    f = np.fft.rfftfreq(n, dt)
    width = max(1, P.size // 256)
    Ps = moving_average(P, width)
    top = Ps[1:].max(initial=0.0)
    f_min, f_max = 3.0 / (n * dt), 0.4 / dt
    if not np.isfinite(top) or top <= 0:
        return f_min, f_max
    hit = np.flatnonzero(Ps >= floor * top)
    hit = hit[hit > 0]
    lo = max(f[hit[0]], f_min) if hit.size else f_min
    hi = min(f[hit[-1]], f_max) if hit.size else f_max
    if hi <= lo * np.exp(4 * DEFAULT_STEP):
        lo, hi = f_min, f_max
    return float(lo), float(hi)


@dataclass
class FitLines:
    """The frequencies a local frequency-domain fit uses, with Y and the effective input X.

    ``dt`` set: the model response is the ZOH-sampled H(z) (exact); None: the continuous G
    times the hold response, which ``X`` then includes. ``transient``: free responses of the
    model must be projected out: the unfinished tail of a record from rest (``tail_shift`` =
    N, its length) or, on the lines of a periodic record, what is left of the start from rest
    in periods that are not yet steady (``tail_shift`` = 0). ``output_response``: the output
    filter's response at ``f``."""

    f: np.ndarray
    Y: np.ndarray
    X: np.ndarray
    dt: float | None
    transient: bool
    output_response: np.ndarray
    tail_shift: int = 0

    @property
    def energy(self) -> float:
        return float(np.sum(np.abs(self.Y) ** 2))


@dataclass
class RecordSpectrum:
    """The log-frequency grid the scans use, and the lines local fits use (``lines``).

    On the grid, X(f_i) = P(f_i) F(f_i) U(f_i) (hold and output-filter responses) so that the
    continuous model G gives Y ~ G X. A periodic record's grid takes each point's values from
    the nearest excited line of the period-averaged spectrum (a record of few periods has no
    input between its lines)."""

    f: np.ndarray
    step: float
    Y: np.ndarray
    X: np.ndarray
    lines: FitLines
    periodic: bool = False

    @property
    def energy(self) -> float:
        return float(np.sum(np.abs(self.Y) ** 2))

    def cost(self, G: np.ndarray) -> float:
        """sum_i |Y_i - G_i X_i|^2 for a model response G on the grid."""
        return float(np.sum(np.abs(self.Y - G * self.X) ** 2))


def _filter_response(problem, f: np.ndarray) -> np.ndarray:
    if problem.output_filter is None:
        return np.ones(f.size, dtype=complex)
    impulse = np.zeros(problem.y.size)
    impulse[0] = 1.0
    return dtft(problem.output_filter(impulse, problem.dt), f, problem.dt)


def record_spectrum(problem, step: float = DEFAULT_STEP, max_lines: int = 400) -> RecordSpectrum:
    """The spectra of a problem's record (see the module and class docstrings)."""
    dt = problem.dt
    lines = periodic_lines(problem.u, problem.y, dt) if problem.hold == "zoh" else None
    if lines is not None and lines.f.size >= 8:
        return _periodic_spectrum(problem, lines, step, max_lines)
    f_lo, f_hi = excited_band(problem.u, dt)
    f = f_lo * np.exp(step * np.arange(int(np.floor(np.log(f_hi / f_lo) / step)) + 1))
    out = _filter_response(problem, f)
    U, Y = dtft(np.vstack([problem.u, problem.y]), f, dt)
    hold = hold_response(f, dt, problem.hold)
    exact = problem.hold == "zoh"
    fit = FitLines(f, Y, U * out * (1.0 if exact else hold), dt if exact else None, True, out, problem.y.size)
    return RecordSpectrum(f, step, Y, U * out * hold, fit)


def _periodic_spectrum(problem, lines: "PeriodicLines", step: float, max_lines: int) -> RecordSpectrum:
    """Grid from the nearest excited line; local fits on (at most ``max_lines``) exact lines."""
    dt = problem.dt
    f_lo, f_hi = excited_band(problem.u, dt)
    band = (lines.f <= f_hi) | (np.arange(lines.f.size) < 8)
    fl = lines.f[band]
    lines = dataclasses.replace(lines, f=fl, U=lines.U[band], Y=lines.Y[band],
                                line_var=None if lines.line_var is None else lines.line_var[band])
    pick = np.unique(np.round(np.geomspace(1, fl.size, min(max_lines, fl.size))).astype(int) - 1)
    f_fit = fl[pick]
    out_fit = _filter_response(problem, f_fit)
    fit = FitLines(f_fit, lines.Y[pick], lines.U[pick] * out_fit, dt, True, out_fit, 0)
    f = fl[0] * np.exp(step * np.arange(int(np.floor(np.log(fl[-1] / fl[0]) / step)) + 1))
    nearest = np.clip(np.searchsorted(fl, f), 1, fl.size - 1)
    nearest = np.where(np.abs(fl[nearest - 1] - f) < np.abs(fl[nearest] - f), nearest - 1, nearest)
    # repeated lines (where the grid is finer than the lines) share their weight
    counts = np.bincount(nearest, minlength=fl.size)[nearest]
    w = 1.0 / np.sqrt(counts)
    out = _filter_response(problem, fl[nearest])
    X = lines.U[nearest] * out * hold_response(fl[nearest], dt, "zoh") * w
    return RecordSpectrum(f, step, lines.Y[nearest] * w, X, fit, periodic=True)


# ---------------------------------------------------------------------------------------------
# Periodic records
# ---------------------------------------------------------------------------------------------
@dataclass
class PeriodicLines:
    """Period-averaged lines of a periodic record.

    period: samples per period P; periods: M steady periods averaged (after ``skipped``);
    start: first sample used; f: line frequencies [Hz]; U, Y: averaged DFT lines (excited
    lines only); line_var: variance of the averaged Y per line from the period scatter
    (None when M < 2); noise_var: white-noise variance per sample, pooled over all lines of
    the period scatter (None when M < 2).
    """

    period: int
    periods: int
    skipped: int
    start: int
    f: np.ndarray
    U: np.ndarray
    Y: np.ndarray
    line_var: np.ndarray | None
    noise_var: float | None


def detect_period(u: np.ndarray, min_period: int = 16, threshold: float = 0.98) -> int | None:
    """Smallest lag P (in samples) at which the input repeats itself, or None.

    The normalised autocorrelation sum u[k] u[k+P] / sqrt(sum u[k]^2 sum u[k+P]^2) over the
    overlap must exceed ``threshold`` at P, and at 2P too when the record holds three periods.
    """
    u = np.asarray(u, dtype=float) - np.mean(u)
    n = u.size
    if n < 2 * min_period:
        return None
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    U = np.fft.rfft(u, nfft)
    acf = np.fft.irfft(np.abs(U) ** 2, nfft)[:n]
    e = np.cumsum(u[::-1] ** 2)[::-1]  # energy of u[k:] ...
    head = np.cumsum(u**2)  # ... and of u[:k]
    lags = np.arange(min_period, n // 2 + 1)
    norm = np.sqrt(head[n - 1 - lags] * e[lags])
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(norm > 0, acf[lags] / norm, 0.0)
    below = np.flatnonzero(r < 0.5)  # a repeat only counts once the signal has decorrelated
    if below.size == 0:
        return None
    for P in lags[(r > threshold) & (lags > lags[below[0]])]:
        if 3 * P <= n:
            r2 = u[: n - 2 * P] @ u[2 * P :] / np.sqrt((u[: n - 2 * P] @ u[: n - 2 * P]) * (u[2 * P :] @ u[2 * P :]))
            if r2 <= threshold:
                continue
        return int(P)
    return None


def periodic_lines(
    u: np.ndarray, y: np.ndarray, dt: float, period: int | None = None, skip: int | None = None, floor: float = 1e-6
) -> PeriodicLines | None:
    """Average the steady periods of a periodic record (None when it holds < 2 periods).

    ``skip`` periods are dropped as the transient (default 1: the first period holds the
    response to the start from rest). Lines whose input power is below ``floor`` of the largest are left out (the
    nulls of a PRBS, the even lines of an inverse-repeat sequence).
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    P = period or detect_period(u)
    if not P:
        return None
    total = u.size // P
    if total < 2:
        return None
    skipped = 1 if skip is None else min(int(skip), total - 1)
    M = total - skipped
    start = skipped * P
    Us = np.fft.rfft(u[start : start + M * P].reshape(M, P), axis=1)
    Ys = np.fft.rfft(y[start : start + M * P].reshape(M, P), axis=1)
    U, Y = Us.mean(axis=0), Ys.mean(axis=0)
    f = np.fft.rfftfreq(P, dt)
    power = np.abs(U) ** 2
    keep = (power >= floor * power[1:].max(initial=0.0)) & (f > 0)
    line_var = noise_var = None
    if M >= 2:
        # residual of each period around the mean, per line: var of the mean = S / (M (M - 1))
        S = np.sum(np.abs(Ys - Y) ** 2, axis=0)
        line_var = (S / (M * (M - 1)))[keep]
        # time-domain scatter of the periods: the white-noise variance per sample
        seg = y[start : start + M * P].reshape(M, P)
        noise_var = float(np.sum((seg - seg.mean(axis=0)) ** 2) / (P * (M - 1)))
    return PeriodicLines(int(P), int(M), int(skipped), int(start), f[keep], U[keep], Y[keep], line_var, noise_var)
