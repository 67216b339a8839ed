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

A calibration run (``mbus-run configs/water_calibration.yaml``) measures every length through
the configured backend, saves every record (``records/length_XX.XXXmm.csv`` + ``.json``) before
estimating anything, writes the calibration file (NPZ arrays + JSON sidecar with frequency grid,
pair identity, reference medium, date, band) and the figures ``fig5_3_gtot.png`` and
``fig5_4_gtr.png``.

Also here, for compensators and the excitation design: :class:`SpectralFilter` (a frequency
response applied to records along axis 0, with its exact transpose) and
:func:`coloured_noise_standard_errors` (sandwich standard errors when the fitted record's noise
has passed a known linear filter).
"""
from __future__ import annotations

import datetime as _dt
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy import fft as sfft

from mbus_framework.errors import ConfigError, DataError

FORMAT = "mbus-calibration/1"
DEFAULT_LENGTHS = [0.0, 0.005, 0.010, 0.015, 0.020, 0.025]


class CalibrationOptions(BaseModel):
    """The config's top-level ``calibration:`` section."""

    model_config = ConfigDict(extra="forbid")
    lengths: list[float] = Field(
        default_factory=lambda: list(DEFAULT_LENGTHS), description="reference-medium lengths [m] (0 allowed)"
    )
    reference: str = Field("water", description="name of the reference medium (recorded in the file)")
    pair: str | None = Field(None, description="transducer pair identity (default: the backend's, if it knows)")
    output: str | None = Field(
        None, description="calibration file to write (.npz, JSON sidecar beside it); default <run_dir>/calibration.npz"
    )
    band: list[float] | None = Field(
        None, description="[f_lo, f_hi] Hz to report and check (default: the rig's pair band, else 0.3-0.7 MHz)"
    )
    analysis: Literal["auto", "periodic", "transient"] = Field(
        "auto", description="periodic: steady-state periods (>= 2 whole periods needed); auto picks it when possible"
    )
    max_log_se: float = Field(0.05, gt=0, description="reliable where SE(ln|G_TR|) [Np] and SE(arg G_TR) [rad] are below")
    floor_db: float = Field(-40.0, lt=0, description="reliable only where |G_TR| is within this of its peak [dB]")

    @model_validator(mode="after")
    def _check(self):
        if len(self.lengths) < 2:
            raise ValueError("lengths: give at least two lengths")
        if any(x < 0 for x in self.lengths):
            raise ValueError("lengths: must be >= 0 (metres)")
        if len(set(self.lengths)) != len(self.lengths):
            raise ValueError("lengths: must be distinct")
        if self.band is not None and (len(self.band) != 2 or not 0 <= self.band[0] < self.band[1]):
            raise ValueError("band: expected [f_lo, f_hi] with 0 <= f_lo < f_hi (Hz)")
        return self


# ---------------------------------------------------------------------------------------------
# Estimation
# ---------------------------------------------------------------------------------------------
def hold_response(f: np.ndarray, dt: float, hold: str = "zoh") -> np.ndarray:
    """Frequency response of the input hold: ZOH e^{-i pi f h} sinc(f h), FOH sinc^2(f h)."""
    x = np.asarray(f, dtype=float) * dt
    if hold == "zoh":
        return np.exp(-1j * np.pi * x) * np.sinc(x)
    if hold == "foh":
        return np.sinc(x) ** 2 + 0j
    raise ValueError(f"hold must be 'zoh' or 'foh', not {hold!r}")


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


# ---------------------------------------------------------------------------------------------
# Frequency-domain filters of records (used by compensators and excitation design)
# ---------------------------------------------------------------------------------------------
class SpectralFilter:
    """x -> first n samples of IFFT(H(f) FFT(x zero-padded to nfft >= 2n)), along axis 0.

    ``response(f)`` gives H on the rfft grid; it is evaluated once per (n, dt).
    """

    def __init__(self, response: Callable[[np.ndarray], np.ndarray]):
        self.response = response
        self._cache: dict[tuple[int, float], tuple[int, np.ndarray]] = {}

    def gain(self, n: int, dt: float) -> tuple[int, np.ndarray]:
        key = (int(n), float(dt))
        if key not in self._cache:
            nfft = sfft.next_fast_len(2 * n, real=True)
            self._cache[key] = (nfft, np.asarray(self.response(sfft.rfftfreq(nfft, dt)), dtype=complex))
        return self._cache[key]

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        n = x.shape[0]
        nfft, H = self.gain(n, dt)
        X = sfft.rfft(x, nfft, axis=0)
        return sfft.irfft(X * (H if x.ndim == 1 else H[:, None]), nfft, axis=0)[:n]

    def adjoint(self, x: np.ndarray, dt: float) -> np.ndarray:
        """The transpose of this linear map (pad, filter by conj(H), truncate)."""
        x = np.asarray(x, dtype=float)
        n = x.shape[0]
        nfft, H = self.gain(n, dt)
        X = sfft.rfft(x, nfft, axis=0)
        Hc = np.conj(H)
        return sfft.irfft(X * (Hc if x.ndim == 1 else Hc[:, None]), nfft, axis=0)[:n]



def coloured_noise_standard_errors(
    jacobian: np.ndarray, noise_std: float, noise_filter: SpectralFilter | None, dt: float
) -> np.ndarray:
    """Standard errors of a least-squares fit whose noise is sigma * (filter applied to white noise).

    Cov = (J^T J)^-1 J^T Sigma J (J^T J)^-1 with Sigma = sigma^2 F F^T (F the filter as a matrix),
    i.e. sigma^2 (J^T J)^-1 (F^T J)^T (F^T J) (J^T J)^-1; without a filter, sigma^2 (J^T J)^-1.
    ``jacobian``: (N, p) free columns of d yhat / d theta of the fitted problem.
    """
    J = np.asarray(jacobian, dtype=float)
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms
    A = np.linalg.pinv(Js.T @ Js)
    if noise_filter is None:
        cov = noise_std**2 * A
    else:
        FtJ = noise_filter.adjoint(Js, dt)
        cov = noise_std**2 * A @ (FtJ.T @ FtJ) @ A
    return np.sqrt(np.clip(np.diag(cov), 0, None)) / norms


# ---------------------------------------------------------------------------------------------
# The calibration file
# ---------------------------------------------------------------------------------------------
@dataclass
class Calibration(_TransducerResponse):
    """A saved G_TR(f): what :mod:`plugins.compensators.transfer_function` loads by path."""

    f: np.ndarray
    log_G_TR: np.ndarray
    reliable: np.ndarray
    se_log_magnitude: np.ndarray
    se_phase: np.ndarray
    usable: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None


    def response(self, f: np.ndarray, band: tuple[float, float] | None = None, extend: bool = False) -> np.ndarray:
        """G_TR at frequencies f [Hz].

        Inside ``band`` (default: the reliable band; never wider) log-magnitude and unwrapped
        phase are interpolated linearly between reliable lines. Outside it the result is 0, or
        with ``extend`` the raw estimate, interpolated (real and imaginary parts) between the
        usable lines: noisy, but of the right size, which is what a filter needs where the rig
        still passes a little.
        """
        f = np.abs(np.asarray(f, dtype=float))
        lo, hi = band or self.reliable_band
        r0, r1 = self.reliable_band
        lo, hi = max(lo, r0), min(hi, r1)
        sel = self.reliable & (self.f >= lo) & (self.f <= hi)
        fs, lg = self.f[sel], self.log_G_TR[sel]
        if fs.size < 2:
            raise DataError(f"{self.path}: fewer than two reliable calibration lines in {lo:g}-{hi:g} Hz")
        inside = (f >= fs[0]) & (f <= fs[-1])
        out = np.zeros(f.shape, dtype=complex)
        out[inside] = np.exp(np.interp(f[inside], fs, lg.real) + 1j * np.interp(f[inside], fs, lg.imag))
        if extend:
            ok = self.usable if self.usable is not None else np.isfinite(self.log_G_TR)
            ok = ok & np.isfinite(self.log_G_TR)
            fu = np.r_[0.0, self.f[ok]]
            gu = np.r_[0.0, np.exp(self.log_G_TR[ok])]
            outside = ~inside & (f <= fu[-1])
            out[outside] = np.interp(f[outside], fu, gu.real) + 1j * np.interp(f[outside], fu, gu.imag)
        return out


def save_calibration(path: str | Path, est: TransferEstimate, meta: dict[str, Any]) -> tuple[Path, Path]:
    """Write ``path`` (.npz arrays) and its JSON sidecar atomically; returns both paths."""
    from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_npz

    path = Path(path)
    if path.suffix.lower() != ".npz":
        path = path.with_suffix(".npz")
    atomic_write_npz(
        path,
        f=est.f,
        log_G_TR=est.log_G_TR,
        gamma=est.gamma,
        se_log_magnitude=est.se_log_magnitude,
        se_phase=est.se_phase,
        reliable=est.reliable,
        lengths=est.lengths,
        G_tot=est.G_tot,
        delays_s=est.delays_s,
        usable=est.usable,
    )
    sidecar = path.with_suffix(".json")
    atomic_write_json(sidecar, {"format": FORMAT, "arrays": path.name, **meta})
    return path, sidecar


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration written by :func:`save_calibration` (give the .npz or the .json)."""
    path = Path(path)
    npz, sidecar = path.with_suffix(".npz"), path.with_suffix(".json")
    if not npz.is_file():
        raise DataError(f"{npz}: calibration file not found (run the calibration config first)")
    meta: dict[str, Any] = {}
    if sidecar.is_file():
        try:
            meta = json.loads(sidecar.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise DataError(f"{sidecar}: unreadable calibration sidecar ({type(exc).__name__})") from None
        if meta.get("format") != FORMAT:
            raise DataError(f"{sidecar}: not an mbus calibration (format {meta.get('format')!r}, expected {FORMAT})")
    try:
        with np.load(npz, allow_pickle=False) as z:
            cal = Calibration(
                f=z["f"], log_G_TR=z["log_G_TR"], reliable=z["reliable"].astype(bool),
                se_log_magnitude=z["se_log_magnitude"], se_phase=z["se_phase"],
                usable=z["usable"].astype(bool) if "usable" in z.files else None, meta=meta, path=npz,
            )
    except (KeyError, ValueError, OSError) as exc:
        raise DataError(f"{npz}: not a readable calibration ({type(exc).__name__}: {exc})") from None
    if not cal.reliable.any():
        raise DataError(f"{npz}: calibration has no reliable frequency lines")
    return cal


# ---------------------------------------------------------------------------------------------
# The calibration run
# ---------------------------------------------------------------------------------------------
def parse_options(raw: dict | None, source: str) -> CalibrationOptions:
    from mbus_framework.pipeline.config import validate_options

    return validate_options(CalibrationOptions, raw or {}, "calibration", source)


def _period_samples(info: dict, n: int, analysis: str, source: str) -> int | None:
    p = info.get("period_samples")
    whole = p is not None and abs(p - round(p)) < 1e-6 and round(p) >= 4 and n >= 2 * round(p)
    if analysis == "periodic" and not whole:
        raise ConfigError(
            f"{source}: calibration.analysis: periodic needs an excitation with an integer number of samples "
            f"per period and at least two periods (e.g. prbs with periods: 2)"
        )
    if analysis == "transient" or not whole:
        return None
    return int(round(p))


def _record_name(length: float) -> str:
    return f"length_{length * 1e3:06.3f}mm"


def run_calibration(config_path, overrides=None, out_dir=None, progress=None) -> str:
    """Measure the reference medium at every length, estimate G_TR and gamma, save and plot.

    Returns a readable summary. Files go to ``out_dir`` (default: a new run folder).
    """
    from mbus_framework.interfaces.backend import AcquisitionContext
    from mbus_framework.pipeline.config import load_config
    from mbus_framework.pipeline.run import build_components, new_run_dir
    from mbus_framework.interfaces.sample import Sample
    from mbus_framework.pipeline.storage import atomic_write_json, atomic_write_text, write_waveforms
    import yaml

    source = str(config_path)
    config = load_config(config_path, overrides)
    opts = parse_options(config.calibration, source)
    c = build_components(config, source)
    if config.backend.name == "simulated" and getattr(c.backend.options, "wave", None) is None:
        raise ConfigError(
            f"{source}: calibration: the simulated rig needs backend.options.wave (a reference propagation path)"
        )
    waveform = c.excitation.waveform()
    period = _period_samples(waveform.info, len(waveform.u), opts.analysis, source)
    run_dir = Path(out_dir) if out_dir else new_run_dir(config, source)
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))

    lengths = sorted(opts.lengths)
    if progress:
        progress.start("calibration: measuring the reference", total=len(lengths))
    records, files = [], []
    try:
        for j, length in enumerate(lengths):
            sample = Sample(length, config.sample.diameter, config.sample.density)
            name = _record_name(length)
            context = AcquisitionContext(waveform, sample, c.model, c.registry, run_dir / "records" / name, source)
            m = _backend_for_record(c.backend, j).acquire(context)
            write_waveforms(run_dir / "records" / f"{name}.csv", m.t, m.u, m.y)
            atomic_write_json(run_dir / "records" / f"{name}.json", {"length_m": length, "meta": m.meta, "dt_s": m.dt})
            records.append((m.t, m.u, m.y))
            files.append(f"records/{name}.csv")
            if progress:
                progress.advance(1, f"{length * 1e3:g} mm")
    finally:
        if progress:
            progress.stop()

    pair_name = opts.pair or _backend_pair(c.backend) or "unnamed transducer pair"
    band = tuple(opts.band) if opts.band else _default_band(c.backend)
    est = estimate_transfer(
        records, lengths, config.model.hold, period, opts.max_log_se, opts.floor_db, band
    )
    truth = getattr(c.backend, "true_transducer_response", None)
    check = compare_with_truth(est.f, est.G_TR, truth(est.f), band) if truth else None
    meta = {
        "pair": pair_name,
        "reference": opts.reference,
        "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        "lengths_m": lengths,
        "band_hz": list(band),
        "reliable_band_hz": list(est.reliable_band),
        "pivot_hz": est.pivot_hz,
        "sample_rate_hz": 1.0 / float(records[0][0][1] - records[0][0][0]),
        "analysis": "periodic" if period else "transient",
        "period_samples": period,
        "hold": config.model.hold,
        "n_lines": int(est.f.size),
        "n_reliable_lines": int(est.reliable.sum()),
        "reference_sound_speed_m_s": est.sound_speed(band),
        "delays_s": est.delays_s.tolist(),
        "excitation": {"name": config.excitation.name, **{k: v for k, v in waveform.info.items() if _scalar(v)}},
        "backend": config.backend.name,
        "config": source,
        "run_dir": str(run_dir),
        "records": files,
        "check_against_true_response": check,
    }
    outputs = [save_calibration(run_dir / "calibration.npz", est, meta)]
    if opts.output:
        outputs.append(save_calibration(opts.output, est, meta))
    plots = []
    if config.output.plots:
        plots = write_calibration_plots(run_dir, est, band, truth, pair_name)
    atomic_write_json(run_dir / "calibration_summary.json", {**meta, "files": [str(p) for o in outputs for p in o] + plots})
    return summary_text(meta, est, outputs, plots)


def _backend_for_record(backend, j: int):
    """A virtual rig with a ``seed`` gets seed + j for record j: independent noise per length,
    as separate lab measurements have."""
    seed = getattr(backend.options, "seed", None)
    if j == 0 or not isinstance(seed, int):
        return backend
    return type(backend)(backend.options.model_copy(update={"seed": seed + j}))


def _scalar(v) -> bool:
    return isinstance(v, (int, float, str, bool)) or v is None


def _backend_pair(backend) -> str | None:
    ident = getattr(backend, "transducer_identity", None)
    return ident() if callable(ident) else None


def _default_band(backend) -> tuple[float, float]:
    pair = getattr(backend, "pair", None)
    if pair is not None and hasattr(pair, "band"):
        return pair.band()
    return (0.3e6, 0.7e6)


def summary_text(meta: dict, est: TransferEstimate, outputs, plots) -> str:
    lo, hi = meta["band_hz"]
    rlo, rhi = meta["reliable_band_hz"]
    sel = (est.f >= lo) & (est.f <= hi)
    lines = [
        f"transducer calibration: {meta['pair']} with {meta['reference']} ({meta['backend']} backend)",
        f"  lengths [mm]: {', '.join(f'{x * 1e3:g}' for x in meta['lengths_m'])}  "
        f"({meta['analysis']} analysis, {meta['n_lines']} lines, hold {meta['hold']})",
        f"  reliable band: {rlo / 1e6:.3f}-{rhi / 1e6:.3f} MHz ({meta['n_reliable_lines']} lines); "
        f"checked band {lo / 1e6:.3f}-{hi / 1e6:.3f} MHz",
        f"  |G_TR| peak {20 * np.log10(np.max(np.abs(est.G_TR[sel]))):.2f} dB at "
        f"{est.f[sel][np.argmax(np.abs(est.G_TR[sel]))] / 1e6:.3f} MHz; "
        f"median SE of ln|G_TR| in band {np.median(est.se_log_magnitude[sel]) * 8.686:.3f} dB, "
        f"of arg G_TR {np.degrees(np.median(est.se_phase[sel])):.2f} deg",
        f"  reference sound speed from Im gamma: {meta['reference_sound_speed_m_s']:.1f} m/s",
    ]
    chk = meta.get("check_against_true_response")
    if chk:
        lines.append(
            f"  vs the rig's true transducer response: max |error| {chk['max_abs_magnitude_error_db']:.3f} dB, "
            f"{chk['max_abs_phase_error_deg']:.2f} deg (rms {chk['rms_magnitude_error_db']:.3f} dB, "
            f"{chk['rms_phase_error_deg']:.2f} deg)"
        )
    for npz, side in outputs:
        lines.append(f"  calibration file: {npz} (+ {side.name})")
    for p in plots:
        lines.append(f"  figure: {Path(meta['run_dir']) / p}")
    lines.append(f"  records: {Path(meta['run_dir']) / 'records'}")
    return "\n".join(lines)


def write_calibration_plots(run_dir: Path, est: TransferEstimate, band, truth, pair_name: str) -> list[str]:
    """Fig. 5.3 (|G_tot| per length and |G_TR|) and Fig. 5.4 (G_TR vs the true response)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lo, hi = band
    view = (est.f > 0) & (est.f <= min(2.0 * hi, est.f[-1]))
    fm = est.f[view] / 1e6
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for length, g in zip(est.lengths, est.G_tot):
        ax.plot(fm, 20 * np.log10(np.abs(g[view]) + 1e-300), lw=0.7, label=f"|G_tot|, {length * 1e3:g} mm")
    ax.plot(fm, 20 * np.log10(np.abs(est.G_TR[view])), "k", lw=1.6, label="|G_TR| (fit)")
    ax.axvspan(lo / 1e6, hi / 1e6, color="0.9", zorder=0)
    ax.set_xlabel("frequency [MHz]")
    ax.set_ylabel("magnitude [dB]")
    peak = 20 * np.log10(np.max(np.abs(est.G_TR[view])))
    ax.set_ylim(peak - 60, peak + 10)
    ax.set_title(f"Fig. 5.3: |G_tot| through the reference at each length, and |G_TR|\n{pair_name}", fontsize=10)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(run_dir / "fig5_3_gtot.png", dpi=110)
    plt.close(fig)

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7.5, 6), sharex=True)
    rel = est.reliable & view
    a1.plot(fm, 20 * np.log10(np.abs(est.G_TR[view])), lw=1.2, label="estimated (multi-length fit)")
    a1.plot(est.f[rel] / 1e6, 20 * np.log10(np.abs(est.G_TR[rel])), ".", ms=2, color="C0", label="reliable lines")
    phase_est = est.log_G_TR.imag[view]
    if truth is not None:
        gt = truth(est.f[view])
        a1.plot(fm, 20 * np.log10(np.abs(gt)), "--", lw=1.2, color="k", label="true (virtual rig)")
        k = np.argmin(np.abs(est.f[view] - est.pivot_hz))
        ph_true = unwrap_from(np.angle(gt), int(k))
        ph_true += 2 * np.pi * np.round((phase_est[k] - ph_true[k]) / (2 * np.pi))
        a2.plot(fm, np.degrees(ph_true), "--", lw=1.2, color="k", label="true (virtual rig)")
    a2.plot(fm, np.degrees(phase_est), lw=1.2, label="estimated")
    for a in (a1, a2):
        a.axvspan(lo / 1e6, hi / 1e6, color="0.9", zorder=0)
        a.legend(fontsize=8)
    a1.set_ylabel("|G_TR| [dB]")
    a1.set_ylim(20 * np.log10(np.max(np.abs(est.G_TR[view]))) - 50, None)
    a2.set_ylabel("arg G_TR [deg]")
    sel = (est.f >= lo) & (est.f <= hi)
    span = np.degrees(est.log_G_TR.imag[sel])
    a2.set_ylim(span.min() - 360, span.max() + 360)
    a2.set_xlabel("frequency [MHz]")
    a1.set_title(f"Fig. 5.4: transducer pair response G_TR, estimated vs true\n{pair_name}", fontsize=10)
    fig.tight_layout()
    fig.savefig(run_dir / "fig5_4_gtr.png", dpi=110)
    plt.close(fig)
    return ["fig5_3_gtot.png", "fig5_4_gtr.png"]
