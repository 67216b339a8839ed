"""When is a minimum the answer? Noise-level estimates and the residual tests.

A local minimum of a wave model leaves a *part of the response* in the residual: a delayed or
mistuned copy of the signal, i.e. something a linear filter of the input explains. The global
minimum of a correct model leaves only noise. Whiteness of the residual alone cannot tell
them apart (local minima with nearly white residuals and a cost 1.1-3x the truth's exist), so
a minimum is accepted only when its cost is consistent with the noise level measured without
the model:

* **Residual-input test** (always). A finite-impulse-response filter of M lags of the input
  is fitted to the residual r by least squares. Its explained energy E_M is what is left of
  the response; with white noise of variance sigma^2 alone, E_M ~ sigma^2 chi^2_M, so

      F = (E_M / M) / ((||r||^2 - E_M) / (N - M - p))  ~  F(M, N - M - p)

  and the model-free noise variance is s_FIR^2 = (||r||^2 - E_M) / (N - M - p). A misfit at
  longer lags than M (a slow wave arriving late) shows in the normalised cross-correlation
  rho_k of residual and input, N(0, 1/N) for white noise at every lag k = 0..N/2; its largest
  value is tested with a Bonferroni bound. (MATLAB's ``resid`` shows the same cross-correlation.)
  Significance is not size: on a long record a harmless few per cent of input-related residual
  (a compensation that is not exact) is significant at p = 1e-9 while every estimate is within
  0.2 % of the truth. So the structure rejects a minimum only when it is significant (p below
  ``significance``) *and* large: its excess energy fraction

      e = max((E_M - M s_FIR^2) / ||r||^2,  rho_max^2 - 2 ln(N/2) / N)

  (what a better fit could at most remove from the residual energy beyond what noise alone puts
  into M lags or into the largest of N/2 cross-correlations) must exceed ``min_excess``
  (default 0.03: the residual energy could fall by more than 3 %, the nrmse by more than
  1.5 %). A local minimum of a wave model leaves a part of the response far above that (a cost
  1.1-3x the truth's is an excess of 9-67 %).
* **Repeated periods** (periodic records): the scatter of the steady-state periods gives
  sigma^2 without any model (:func:`~mbus_framework.estimation.spectral.periodic_lines`);
  the residual variance must not exceed it beyond its sampling spread. The scatter is the
  noise only once the start from rest has died out: a lightly damped chain still rings in the
  averaged periods and its scatter is 2-3000x sigma^2. A scatter more than ``STEADY_AGREEMENT``
  above the local-polynomial estimate (next item; the two agree within +-4 % on steady
  records) is therefore no noise estimate and is left out.
* **Local polynomial method** (every record,
  :func:`~mbus_framework.estimation.noise_level.local_polynomial_variance`): what no response
  and transient smooth over 15 DFT lines explains, the median over windows; within 6 % of the
  true sigma on every record of the convergence benchmark (ringing chains, broadband inputs
  whose spectrum reaches Nyquist). Stored as ``out_of_band`` (the part of the spectrum the
  input does not explain); used to route the search, not for acceptance. (The median power of
  the top quarter of the spectrum, :func:`out_of_band_variance`, was used before: it holds
  signal, up to 100x sigma^2, wherever the input and the medium reach Nyquist.)
* **Whiteness** (mean |autocorrelation| at lags 1-10), as before, as a second condition.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import special
from scipy.linalg import solve_toeplitz

from mbus_framework.estimation.exploration import residual_autocorrelation
from mbus_framework.estimation.noise_level import local_polynomial_variance
from mbus_framework.estimation.spectral import periodic_lines


@dataclass
class NoiseEstimates:
    """Model-free estimates of the output-noise variance [output units^2] (None: unavailable):
    ``periods`` from the steady periods' scatter (``periods_dof`` degrees of freedom),
    ``out_of_band`` from the local polynomial method."""

    periods: float | None = None
    periods_dof: int = 0
    out_of_band: float | None = None

    def as_dict(self) -> dict:
        return {
            "periods_std": None if self.periods is None else float(np.sqrt(self.periods)),
            "periods_dof": self.periods_dof,
            "out_of_band_std": None if self.out_of_band is None else float(np.sqrt(self.out_of_band)),
        }


#: The period scatter counts as the noise only within this factor of the local-polynomial
#: variance (steady records agree within +-4 %; a ringing start from rest puts it 1.3-3000x above).
STEADY_AGREEMENT = 1.25


def estimate_noise(t: np.ndarray, u: np.ndarray, y: np.ndarray) -> NoiseEstimates:
    """Noise variance from the local polynomial method (``out_of_band``) and from repeated
    periods, when the input repeats and the periods are steady (module docstring)."""
    dt = float(t[1] - t[0])
    local = local_polynomial_variance(u, y)
    out = NoiseEstimates(out_of_band=out_of_band_variance(y) if local is None else local)
    lines = periodic_lines(u, y, dt)
    if lines is not None and lines.noise_var is not None:
        if out.out_of_band is None or lines.noise_var <= STEADY_AGREEMENT * out.out_of_band:
            out.periods = lines.noise_var
            out.periods_dof = lines.period * (lines.periods - 1)
    return out


def out_of_band_variance(y: np.ndarray) -> float | None:
    """sigma^2 from the median |Y_k|^2 of the top quarter of the spectrum (white noise:
    |Y_k|^2 is exponential with mean N sigma^2, its median ln 2 times that)."""
    y = np.asarray(y, dtype=float)
    if y.size < 64:
        return None
    Y = np.fft.rfft(y - y.mean())
    top = np.abs(Y[3 * Y.size // 4 : -1]) ** 2
    if top.size < 8:
        return None
    return float(np.median(top) / (np.log(2.0) * y.size))


def default_lags(n: int) -> int:
    """Lags of the residual-input test: N / 16, between 16 and 400."""
    return int(min(400, max(16, n // 16)))


@dataclass
class ResidualTest:
    """Outcome of the residual-input test (see the module docstring).

    ``F``/``lags``: the FIR part; ``max_correlation``/``max_lag``: the largest normalised
    cross-correlation |rho_k| over lags 0..N/2 (a misfit further out than the FIR's lags, a
    wave arriving late); ``p_value`` combines both (twice the smaller)."""

    lags: int
    explained_fraction: float
    F: float
    p_value: float
    noise_std: float
    max_correlation: float = 0.0
    max_lag: int = 0
    p_fir: float = 1.0
    p_correlation: float = 1.0
    excess_fraction: float = 0.0

    def as_dict(self) -> dict:
        return {"lags": self.lags, "explained_fraction": self.explained_fraction, "F": self.F,
                "p_value": self.p_value, "noise_std": self.noise_std,
                "max_correlation": self.max_correlation, "max_lag": self.max_lag,
                "p_fir": self.p_fir, "p_correlation": self.p_correlation, "excess_fraction": self.excess_fraction}


def residual_input_test(r: np.ndarray, u: np.ndarray, n_params: int, lags: int | None = None) -> ResidualTest:
    """Fit r ~ sum_{k<M} h_k u[t-k] (normal equations with the input's autocorrelation, a
    Toeplitz system) and test the explained energy against white noise; and test the largest
    cross-correlation |rho_k| = |sum_t r[t] u[t-k]| / (||r|| ||u||), k = 0..N/2, which is
    N(0, 1/N) for white r whatever the input, with a Bonferroni bound over the lags."""
    r = np.asarray(r, dtype=float)
    u = np.asarray(u, dtype=float)
    n = r.size
    M = lags or default_lags(n)
    M = max(1, min(M, n // 4))
    rr = float(r @ r)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    U = np.fft.rfft(u, nfft)
    R = np.fft.rfft(r, nfft)
    acf_full = np.fft.irfft(np.abs(U) ** 2, nfft)
    cross_full = np.fft.irfft(R * np.conj(U), nfft)  # sum_t r[t] u[t-k]
    acf, cross = acf_full[:M], cross_full[:M]
    if not (np.isfinite(rr) and rr > 0 and acf[0] > 0):
        return ResidualTest(M, 0.0, 0.0, 1.0, float(np.sqrt(max(rr, 0.0) / max(n - n_params, 1))))
    acf = acf.copy()
    acf[0] *= 1.0 + 1e-10  # a hair of ridge: an input with a short period is singular at long lags
    try:
        h = solve_toeplitz(acf, cross)
        explained = float(np.clip(h @ cross, 0.0, rr))
    except np.linalg.LinAlgError:
        explained = 0.0
    dof = max(n - M - n_params, 1)
    rest = max(rr - explained, 1e-300)
    F = (explained / M) / (rest / dof)
    p_fir = float(special.fdtrc(M, dof, F))  # F_{M,dof} upper tail
    K = n // 2
    rho = np.abs(cross_full[:K]) / np.sqrt(rr * acf_full[0])
    k_max = int(np.argmax(rho))
    p_ccf = float(min(1.0, K * 2.0 * special.ndtr(-rho[k_max] * np.sqrt(n))))
    p = float(min(1.0, 2.0 * min(p_fir, p_ccf)))
    excess = max((explained - M * rest / dof) / rr, float(rho[k_max]) ** 2 - 2.0 * np.log(max(K, 2)) / n, 0.0)
    return ResidualTest(M, explained / rr, float(F), p, float(np.sqrt(rest / dof)), float(rho[k_max]), k_max,
                        p_fir, p_ccf, float(excess))


@dataclass
class Verdict:
    """Whether a minimum is accepted, and the evidence."""

    accepted: bool
    reason: str
    residual_test: ResidualTest
    whiteness: float
    noise_ratio: float | None = None  # residual variance / period-scatter variance
    details: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"accepted": self.accepted, "reason": self.reason, "residual_test": self.residual_test.as_dict(),
                "whiteness": self.whiteness, "noise_ratio": self.noise_ratio}


def judge(r: np.ndarray, u: np.ndarray, n_params: int, noise: NoiseEstimates | None, *, significance: float = 1e-3,
          whiteness_threshold: float = 0.1, white_noise: bool = True, lags: int | None = None,
          min_excess: float = 0.03) -> Verdict:
    """Accept a minimum whose residual r is consistent with the noise (module docstring):
    input-related structure rejects it when significant (p < ``significance``) and larger than
    ``min_excess`` of the residual energy.

    ``white_noise`` False (a compensator coloured the noise) skips the whiteness condition."""
    test = residual_input_test(r, u, n_params, lags)
    white = residual_autocorrelation(r)
    s2 = float(r @ r) / max(r.size - n_params, 1)
    ratio = None
    if noise is not None and noise.periods is not None and noise.periods > 0:
        ratio = s2 / noise.periods
    if test.p_value < significance and test.excess_fraction > min_excess:
        return Verdict(False, f"the residual still holds {100 * test.explained_fraction:.2g} % input-related "
                              f"structure (F = {test.F:.3g}, p = {test.p_value:.2g})", test, white, ratio)
    if ratio is not None and noise.periods_dof > 0:
        limit = 1.0 + 4.0 * np.sqrt(2.0 / r.size + 2.0 / noise.periods_dof)
        if ratio > limit:
            return Verdict(False, f"the residual variance is {ratio:.3g} x the noise variance of the repeated "
                                  f"periods (limit {limit:.3g})", test, white, ratio)
    if white_noise and white >= whiteness_threshold:
        return Verdict(False, f"the residuals are not white (mean |autocorrelation| {white:.3g})", test, white, ratio)
    why = f"residual consistent with noise (input-related part p = {test.p_value:.2g}"
    if test.p_value < significance:
        why += (f", significant but small: {100 * test.excess_fraction:.2g} % of the residual energy beyond the "
                f"noise's, not above {100 * min_excess:.3g} %")
    why += f", variance {ratio:.3g} x that of the repeated periods)" if ratio is not None else ")"
    return Verdict(True, why, test, white, ratio)
