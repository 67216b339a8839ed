"""Transducer-pair calibration (Chapter 5): G_TR(w) from a reference medium at several lengths.

Model (eqs. 5.1-5.3): through a reference medium of length l the rig's response is

    G_tot(f; l) = G_TR(f) G_M(f)^(l / l_1) = G_TR(f) exp(l gamma(f)),

so per frequency  ln G_tot(f; l) = ln G_TR(f) + l gamma(f),  linear in l. (Two lengths L and nL
give G_tot(nL) / G_tot(L) = G_M^(n-1): the root in eq. 5.4 is the (n-1)-th, not the n-th as
printed; :func:`two_length_estimate`.) With lengths l_1..l_m (default 0, 5, ..., 25 mm; a zero
length measures G_TR directly) both real parts (ln|G|, attenuation) and imaginary parts
(unwrapped phase, propagation) are fitted by least squares per frequency line:

    [ln|G_tot|, arg G_tot](f; l_j) = [ln|G_TR|, arg G_TR](f) + l_j [Re gamma, Im gamma](f) + e_j

Standard errors of the intercepts come from the residuals (m - 2 degrees of freedom).

Frequency responses. ``periodic`` analysis (a PRBS or multisine of >= 2 whole periods of
integer samples): the first period after the excitation starts is discarded (transient), the
remaining whole periods are averaged and G = Y_k / U_k on the excitation's lines, exact for a
periodic steady state. ``transient`` analysis: G = Y / U of the zero-padded record (exact when the
response has died out within the record). Either way G is divided by the input hold's response
(ZOH: e^{-i pi f h} sinc(f h); FOH: sinc^2(f h)), so G_TR is the continuous-time response
between the held input, as the medium models see it, and the output.

Phase unwrapping is the fragile step (25 mm of water is 17 us, i.e. ~50 rad at 0.5 MHz): each
record's bulk delay tau_j relative to the shortest length is found by cross-correlation (weighted
by |G_ref|^2, refined parabolically), the residual phase arg(G_j e^{i 2 pi f tau_j}) is unwrapped
outwards from the band centre and aligned across lengths there, and 2 pi f tau_j is added back.
Outside the transducer band the phase is noise; lines are flagged ``reliable`` only in the
contiguous band around the centre where |G_TR| is within ``floor_db`` of its peak and the
standard errors of ln|G_TR| [Np] and arg G_TR [rad] stay below ``max_log_se`` (the default 0.05 is
0.43 dB and 2.9 degrees).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mbus_framework.engine.hold import hold_response
from mbus_framework.errors import DataError


# ---------------------------------------------------------------------------------------------
# Estimation
# ---------------------------------------------------------------------------------------------
def onset_index(u: np.ndarray, fraction: float = 0.1) -> int:
    """First sample where |u| exceeds ``fraction`` of its peak."""
    a = np.abs(np.asarray(u, dtype=float))
    hit = np.flatnonzero(a > fraction * a.max())
    return int(hit[0]) if hit.size else 0


def frequency_response(
    u: np.ndarray,
    y: np.ndarray,
    dt: float,
    hold: str = "zoh",
    period_samples: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f [Hz], G(f), |U(f)|) of one record, hold-corrected (see the module docstring).

    With ``period_samples`` P the steady-state periods after the first are averaged and the
    lines are k / (P dt); otherwise the zero-padded record is used.
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if period_samples:
        P = int(period_samples)
        start = onset_index(u) + P
        m = (u.size - start) // P
        if m < 1:
            raise DataError(
                f"periodic analysis needs two whole periods after the excitation starts ({2 * P} samples), "
                f"the record has {u.size - start + P}"
            )
        seg = slice(start, start + m * P)
        U = np.fft.rfft(u[seg].reshape(m, P).mean(axis=0))
        Y = np.fft.rfft(y[seg].reshape(m, P).mean(axis=0))
        f = np.fft.rfftfreq(P, dt)
    else:
        nfft = 2 * u.size
        U = np.fft.rfft(u, nfft)
        Y = np.fft.rfft(y, nfft)
        f = np.fft.rfftfreq(nfft, dt)
    with np.errstate(divide="ignore", invalid="ignore"):
        G = Y / U / hold_response(f, dt, hold)
    return f, G, np.abs(U)


def relative_delay(f: np.ndarray, G: np.ndarray, G_ref: np.ndarray, weight: np.ndarray) -> float:
    """Delay [s] of G relative to G_ref: peak of the weighted cross-correlation, refined parabolically.

    f must be a uniform grid of multiples of df (lines k df); delays are taken in (-T/2, T/2],
    T = 1 / df.
    """
    df = f[1] - f[0]
    k = np.rint(f / df).astype(np.int64)
    C = np.where(np.isfinite(G) & np.isfinite(G_ref), G * np.conj(G_ref), 0.0) * weight
    C = C / (np.abs(C) + 1e-300) * weight  # phase transform keeps the peak sharp; weight keeps the band
    M = 16 * int(2 ** np.ceil(np.log2(k.max() + 1)))
    full = np.zeros(M // 2 + 1, dtype=complex)
    full[k] = C
    r = np.fft.irfft(full, M)
    # r[j] ~ sum C_k e^{i 2 pi k j / M} with C_k ~ e^{-i 2 pi k df tau}: a peak at j = tau df M (mod M).
    j = int(np.argmax(r))
    a, b, c = r[(j - 1) % M], r[j], r[(j + 1) % M]
    denom = a - 2 * b + c
    frac = 0.5 * (a - c) / denom if denom != 0 else 0.0
    pos = (j + frac) / M  # in units of T
    if pos > 0.5:
        pos -= 1.0
    return float(pos / df)


def unwrap_from(phase: np.ndarray, pivot: int) -> np.ndarray:
    """Unwrap along the array outwards from index ``pivot`` (which keeps its value)."""
    out = np.array(phase, dtype=float)
    out[pivot:] = np.unwrap(out[pivot:])
    out[: pivot + 1] = np.unwrap(out[: pivot + 1][::-1])[::-1]
    return out


def log_responses(f: np.ndarray, G: np.ndarray, weight: np.ndarray, pivot: int) -> tuple[np.ndarray, np.ndarray]:
    """Complex logs ln|G_j| + i arg G_j with phases unwrapped consistently across records.

    G: (m, n_f); ``weight``: cross-correlation weight per line (|Y_ref|^2 on usable lines).
    Returns (logs (m, n_f), delays tau_j [s] relative to record 0).
    """
    ref = G[0]
    taus = np.array([relative_delay(f, g, ref, weight) if j else 0.0 for j, g in enumerate(G)])
    logs = np.empty(G.shape, dtype=complex)
    base = None
    for j, g in enumerate(G):
        g = np.where(np.isfinite(g) & (g != 0), g, 1e-300)
        r = unwrap_from(np.angle(g * np.exp(2j * np.pi * f * taus[j])), pivot)
        if base is None:
            base = r[pivot]
        r += 2 * np.pi * np.round((base - r[pivot]) / (2 * np.pi))
        logs[j] = np.log(np.abs(g)) + 1j * (r - 2 * np.pi * f * taus[j])
    return logs, taus


def two_length_estimate(log_G_L: np.ndarray, log_G_nL: np.ndarray, n: float) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 5.4-5.5 corrected: from logs (unwrapped phase) at lengths L and nL (n > 1),

    G_M = (G_tot(nL) / G_tot(L))^(1/(n-1)),  G_TR = G_tot(L) / G_M.  Returns (G_M, G_TR).
    """
    if n <= 1:
        raise ValueError("n must exceed 1 (lengths L and nL with n > 1)")
    log_M = (np.asarray(log_G_nL) - np.asarray(log_G_L)) / (n - 1)
    return np.exp(log_M), np.exp(np.asarray(log_G_L) - log_M)


class _TransducerResponse:
    """G_TR and its reliable band from ``f``, ``log_G_TR`` and the ``reliable`` mask."""

    f: np.ndarray
    log_G_TR: np.ndarray
    reliable: np.ndarray

    @property
    def G_TR(self) -> np.ndarray:
        return np.exp(self.log_G_TR)

    @property
    def reliable_band(self) -> tuple[float, float]:
        idx = np.flatnonzero(self.reliable)
        return (float(self.f[idx[0]]), float(self.f[idx[-1]])) if idx.size else (float("nan"), float("nan"))


@dataclass
class TransferEstimate(_TransducerResponse):
    """Result of :func:`estimate_transfer` (all arrays over the lines f)."""

    f: np.ndarray
    lengths: np.ndarray
    G_tot: np.ndarray  # (m, n_f), hold-corrected
    log_G_TR: np.ndarray  # ln|G_TR| + i arg G_TR (phase unwrapped from the pivot)
    gamma: np.ndarray  # 1/m
    se_log_magnitude: np.ndarray  # Np
    se_phase: np.ndarray  # rad
    reliable: np.ndarray  # bool
    pivot_hz: float
    delays_s: np.ndarray
    usable: np.ndarray


    def sound_speed(self, band: tuple[float, float]) -> float:
        """Reference phase velocity c = -2 pi f / Im gamma, median over ``band`` [m/s]."""
        sel = (self.f >= band[0]) & (self.f <= band[1]) & self.reliable
        if not np.any(sel):
            return float("nan")
        return float(np.median(-2 * np.pi * self.f[sel] / self.gamma.imag[sel]))


def estimate_transfer(
    records: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    lengths: list[float],
    hold: str = "zoh",
    period_samples: int | None = None,
    max_log_se: float = 0.05,
    floor_db: float = -40.0,
    band: tuple[float, float] | None = None,
) -> TransferEstimate:
    """Fit ln G_tot(f; l) = ln G_TR(f) + l gamma(f) per line from records (t, u, y) at ``lengths`` [m]."""
    lengths = np.asarray(lengths, dtype=float)
    if len(records) != lengths.size or lengths.size < 2:
        raise ValueError("need one record per length and at least two lengths")
    order = np.argsort(lengths)
    lengths = lengths[order]
    records = [records[i] for i in order]
    dt = float(records[0][0][1] - records[0][0][0])
    responses = [frequency_response(u, y, dt, hold, period_samples) for _, u, y in records]
    f = responses[0][0]
    if any(r[0].shape != f.shape for r in responses):
        raise DataError("calibration records differ in length or sample rate")
    G = np.array([r[1] for r in responses])
    Umag = np.array([r[2] for r in responses])
    usable = (f > 0) & np.all(Umag > 1e-3 * Umag.max(axis=1, keepdims=True), axis=0) & np.all(np.isfinite(G), axis=0)
    if band is not None:
        centre = np.sqrt(band[0] * band[1]) if band[0] > 0 else 0.5 * band[1]
        pivot = int(np.argmin(np.abs(f - centre) + np.where(usable, 0, np.inf)))
    else:
        mag = np.where(usable, np.abs(G[0]), 0.0)
        pivot = int(np.argmax(np.convolve(mag, np.ones(9) / 9, mode="same")))
    # Weight the delay search by the reference record's output power |G U|^2: lines where U is
    # nearly zero (PRBS nulls) or G is small (outside the band) hardly count.
    weight = np.where(usable, np.abs(np.where(usable, G[0], 0.0) * Umag[0]) ** 2, 0.0)
    logs, taus = log_responses(f, G, weight, pivot)
    X = np.column_stack([np.ones_like(lengths), lengths])
    XtX_inv = np.linalg.inv(X.T @ X)
    coef_re = XtX_inv @ X.T @ logs.real
    coef_im = XtX_inv @ X.T @ logs.imag
    dof = lengths.size - 2
    if dof > 0:
        res_re = logs.real - X @ coef_re
        res_im = logs.imag - X @ coef_im
        s_re = np.sqrt(np.sum(res_re**2, axis=0) / dof)
        s_im = np.sqrt(np.sum(res_im**2, axis=0) / dof)
        c00 = np.sqrt(XtX_inv[0, 0])
        se_mag, se_ph = s_re * c00, s_im * c00
    else:
        se_mag = se_ph = np.full(f.shape, np.nan)
    log_G_TR = coef_re[0] + 1j * coef_im[0]
    gamma = coef_re[1] + 1j * coef_im[1]
    reliable = _reliable(f, log_G_TR.real, se_mag, se_ph, usable, pivot, max_log_se, floor_db)
    return TransferEstimate(
        f=f,
        lengths=lengths,
        G_tot=G,
        log_G_TR=log_G_TR,
        gamma=gamma,
        se_log_magnitude=se_mag,
        se_phase=se_ph,
        reliable=reliable,
        pivot_hz=float(f[pivot]),
        delays_s=taus,
        usable=usable,
    )


def _running_median(x: np.ndarray, width: int = 9) -> np.ndarray:
    from scipy.ndimage import median_filter

    return median_filter(np.where(np.isfinite(x), x, np.inf), size=width, mode="nearest")


def _reliable(f, log_mag, se_mag, se_ph, usable, pivot, max_se, floor_db) -> np.ndarray:
    peak = np.max(np.where(usable, log_mag, -np.inf))
    ok = usable & (log_mag >= peak + floor_db / 20 * np.log(10))
    if np.all(np.isfinite(se_mag)):
        ok &= (_running_median(se_mag) <= max_se) & (_running_median(se_ph) <= max_se)
    out = np.zeros_like(ok)
    if not ok[pivot]:
        return out
    lo = hi = pivot
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    while hi < ok.size - 1 and ok[hi + 1]:
        hi += 1
    out[lo : hi + 1] = True
    return out


def compare_with_truth(f: np.ndarray, G_est: np.ndarray, G_true: np.ndarray, band: tuple[float, float]) -> dict:
    """Largest magnitude error [dB] and phase error [deg] of G_est vs G_true over ``band``."""
    sel = (f >= band[0]) & (f <= band[1])
    ratio = G_est[sel] / G_true[sel]
    mag_db = 20 * np.log10(np.abs(ratio))
    ph_deg = np.degrees(np.angle(ratio))
    return {
        "band_hz": [float(band[0]), float(band[1])],
        "n_lines": int(sel.sum()),
        "max_abs_magnitude_error_db": float(np.max(np.abs(mag_db))),
        "max_abs_phase_error_deg": float(np.max(np.abs(ph_deg))),
        "rms_magnitude_error_db": float(np.sqrt(np.mean(mag_db**2))),
        "rms_phase_error_deg": float(np.sqrt(np.mean(ph_deg**2))),
    }
