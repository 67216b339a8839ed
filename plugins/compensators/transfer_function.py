"""``transfer_function`` compensator (Chapter 5): remove or model the transducer pair G_TR.

G_TR(f) comes from a calibration file (:mod:`mbus_framework.studies.transducer_calibration`, written by a
calibration run such as ``configs/water_calibration.yaml``). It is known only in the band where
the calibration is reliable (``band`` narrows it), so the fit is confined to that band in both
modes: a zero-phase window P(f) (1 inside, raised-cosine edges of ``taper`` times the band width
each, 0 outside) is applied to the record and to the model alike. Outside the band the rig passes
little and what it passes cannot be modelled without G_TR.

``mode: forward`` (default): the record is only band-limited, y_c = P y, and G_TR is put into
the model's output path, yhat = P (G_TR y_model) (and the same for every sensitivity; each
filter's output is cut to the record length, as the data are). Nothing is
divided, so no noise is amplified: the noise is P e, white within the band.

``mode: deconvolve``: eq. 5.6 with regularisation. With Y(f) the record's spectrum,

    Y_d = W Y,   W = P conj(G) / (|G|^2 + lambda(f)),

    wiener:   lambda(f) = |G|^2 N0 / max(S_y(f) - N0, eps)   i.e. W = P (1 / G) (1 - N0 / S_y)_+
    tikhonov: lambda    = weight * max|G|^2, or without ``weight`` N0 / mean_band(S_x)

where N0 = n sigma^2 is the white-noise level per bin (sigma = ``noise_std``, or estimated as
median |Y_k|^2 / (n ln 2) over the bins far outside the band: f > 2.5 f_hi or f < f_lo / 3),
S_y the record's smoothed periodogram and S_x = (S_y - N0) / |G|^2 the medium output's. The model
output is band-limited the same way, W applied after G_TR, i.e. B = W G = P |G|^2 / (|G|^2 + lambda) (real, zero phase),
so data and model stay comparable. The deconvolved noise is W e: amplified where |G| < 1.

In both modes the residual noise is coloured by a known linear filter (:meth:`noise_filter`):
standard errors computed as if the residuals were white noise (s^2 (J^T J)^-1 with s^2 from the
residuals) are then wrong; :func:`coloured_noise_standard_errors` gives the correct sandwich
form. All filters act on the record zero-padded to >= 2n samples (linear, not circular,
convolution) along axis 0, so they are linear maps of outputs and sensitivities alike.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy import fft as sfft

from mbus_framework.compensation.calibration_file import Calibration, load_calibration
from mbus_framework.compensation.filters import (
    SpectralFilter,
    coloured_noise_standard_errors,
)
from mbus_framework.errors import ConfigError, DataError
from mbus_framework.interfaces.backend import Measurement
from mbus_framework.interfaces.compensator import Compensator
from mbus_framework.interfaces.hookspecs import CompensatorSpec, hookimpl


class TransferFunctionOptions(BaseModel):
    """``compensator.options`` of ``transfer_function``."""

    model_config = ConfigDict(extra="forbid")
    calibration: str = Field(description="calibration file (.npz or its .json sidecar); in a config relative to its folder")
    mode: Literal["forward", "deconvolve"] = Field("forward", description="model G_TR (forward) or divide it out")
    regularisation: Literal["wiener", "tikhonov"] = Field("wiener", description="deconvolve: regulariser")
    weight: float | None = Field(None, gt=0, description="tikhonov: lambda / max|G_TR|^2 (default: from the noise level)")
    noise_std: float | None = Field(None, gt=0, description="output noise std (default: estimated out of band)")
    band: list[float] | None = Field(None, description="[f_lo, f_hi] Hz (default: the calibration's reliable band)")
    taper: float = Field(0.1, ge=0, le=0.5, description="raised-cosine edge of the band window, fraction of the band width")

    @model_validator(mode="after")
    def _band(self):
        if self.band is not None and (len(self.band) != 2 or not 0 <= self.band[0] < self.band[1]):
            raise ValueError("band: expected [f_lo, f_hi] with 0 <= f_lo < f_hi (Hz)")
        return self


class Composed:
    """x -> outer(inner(x)), each truncated to the record: the model output passes G_TR (inner)
    and is then observed through the same record-length filter as the data (outer)."""

    def __init__(self, outer: SpectralFilter, inner: SpectralFilter):
        self.outer, self.inner = outer, inner

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        return self.outer(self.inner(x, dt), dt)


def band_window(f: np.ndarray, band: tuple[float, float], taper: float) -> np.ndarray:
    """P(f): 1 inside ``band``, raised-cosine edges of width taper * (f_hi - f_lo) inside it, 0 outside."""
    f = np.abs(np.asarray(f, dtype=float))
    lo, hi = band
    w = taper * (hi - lo)
    P = ((f >= lo) & (f <= hi)).astype(float)
    if w > 0:
        for edge, dist in ((lo, f - lo), (hi, hi - f)):
            ramp = (dist >= 0) & (dist < w)
            P[ramp] = 0.5 * (1 - np.cos(np.pi * dist[ramp] / w))
    return P


def estimate_noise_std(y: np.ndarray, dt: float, band: tuple[float, float]) -> float | None:
    """White-noise std from the periodogram far outside ``band`` (None if too few bins there)."""
    n = y.size
    Y = np.fft.rfft(y - np.mean(y))
    f = np.fft.rfftfreq(n, dt)
    far = ((f > 2.5 * band[1]) & (f < 0.95 * f[-1])) | ((f > 0) & (f < band[0] / 3))
    if far.sum() < 16:
        return None
    return float(np.sqrt(np.median(np.abs(Y[far]) ** 2) / (n * np.log(2))))


class TransferFunctionCompensator(Compensator):
    """Chapter 5 transducer compensation from a calibration file (forward or deconvolve)."""

    Options = TransferFunctionOptions
    summary = "transducer pair G_TR from a calibration: forward model or regularised deconvolution (Ch. 5)"

    def __init__(self, options: TransferFunctionOptions):
        super().__init__(options)
        self.calibration: Calibration = load_calibration(options.calibration)
        lo, hi = self.calibration.reliable_band
        if options.band is not None:
            lo, hi = max(lo, options.band[0]), min(hi, options.band[1])
            if lo >= hi:
                raise ConfigError(
                    f"compensator.options.band: {options.band} does not overlap the calibration's reliable band "
                    f"{self.calibration.reliable_band[0]:g}-{self.calibration.reliable_band[1]:g} Hz"
                )
        self.band = (lo, hi)
        self._window = SpectralFilter(self.window)
        self._transducers = SpectralFilter(lambda f: self.calibration.response(f, self.band, extend=True))
        self._forward = Composed(self._window, self._transducers)
        self._deconvolution: SpectralFilter | None = None
        self._band_limit: SpectralFilter | None = None
        self.last_info: dict = {}

    def transducer_response(self, f: np.ndarray) -> np.ndarray:
        """G_TR(f) from the calibration inside the band, 0 outside."""
        return self.calibration.response(f, self.band)

    def window(self, f: np.ndarray) -> np.ndarray:
        """The band window P(f)."""
        return band_window(f, self.band, self.options.taper)

    # -- Compensator interface -------------------------------------------------------------------
    def apply(self, measurement: Measurement) -> Measurement:
        o = self.options
        info = {
            "name": "transfer_function",
            "mode": o.mode,
            "calibration": str(self.calibration.path),
            "pair": self.calibration.meta.get("pair"),
            "calibration_date": self.calibration.meta.get("date"),
            "band_hz": list(self.band),
        }
        rig_pair = (measurement.meta.get("transducers") or {}).get("name")
        if rig_pair and info["pair"] and rig_pair != info["pair"]:
            info["warning"] = f"the record's transducer pair '{rig_pair}' is not the calibrated '{info['pair']}'"
        if o.mode == "forward":
            self.last_info = info
            y_c = self._window(measurement.y, measurement.dt)
            return replace(measurement, y=y_c, meta={**measurement.meta, "compensation": info})
        y_d, extra = self._deconvolve(measurement.y, measurement.dt)
        info.update(extra)
        self.last_info = info
        return replace(measurement, y=y_d, meta={**measurement.meta, "compensation": info})

    def output_filter(self):
        if self.options.mode == "forward":
            return self._forward
        if self._band_limit is None:
            raise RuntimeError("transfer_function (deconvolve): call apply() before output_filter()")
        return self._band_limit

    def noise_filter(self) -> SpectralFilter | None:
        """The linear map the compensation applies to the record (and so to its noise)."""
        return self._window if self.options.mode == "forward" else self._deconvolution

    # -- deconvolution -----------------------------------------------------------------------------
    def _deconvolve(self, y: np.ndarray, dt: float) -> tuple[np.ndarray, dict]:
        o = self.options
        n = y.size
        nfft = sfft.next_fast_len(2 * n, real=True)
        f = sfft.rfftfreq(nfft, dt)
        G = self.transducer_response(f)
        P = self.window(f)
        G2 = np.abs(G) ** 2
        sigma = o.noise_std or estimate_noise_std(y, dt, self.band)
        if sigma is None:
            raise DataError(
                "transfer_function: too few frequency bins outside the band to estimate the noise; "
                "set compensator.options.noise_std"
            )
        N0 = n * sigma**2  # E|E_k|^2 of white noise, n samples zero-padded
        Y = sfft.rfft(y, nfft)
        from scipy.ndimage import uniform_filter1d  # on use: scipy.ndimage is slow to import

        S_y = uniform_filter1d(np.abs(Y) ** 2, size=15, mode="nearest")
        inband = (f >= self.band[0]) & (f <= self.band[1])
        if o.regularisation == "wiener":
            gain = P * np.clip(1.0 - N0 / np.maximum(S_y, 1e-300), 0.0, 1.0)  # B = W G
            W = np.where(P > 0, gain / np.where(P > 0, G, 1.0), 0.0)
            lam_info = {"wiener_mean_gain_in_band": float(np.mean(gain[inband]))}
        else:
            if o.weight is not None:
                lam = o.weight * float(G2.max())
            else:
                S_x = np.maximum(S_y[inband] - N0, 0.0) / np.maximum(G2[inband], 1e-300)
                lam = N0 / max(float(np.mean(S_x)), 1e-300)
            W = P * np.conj(G) / (G2 + lam)
            gain = P * G2 / (G2 + lam)
            lam_info = {"tikhonov_lambda": float(lam), "tikhonov_lambda_relative": float(lam / G2.max())}
        self._deconvolution = SpectralFilter(_on_grid(f, W))
        self._band_limit = Composed(self._deconvolution, self._transducers)
        y_d = sfft.irfft(Y * W, nfft)[:n]
        extra = {
            "regularisation": o.regularisation,
            "noise_std": float(sigma),
            "noise_std_source": "option" if o.noise_std else "estimated out of band",
            "noise_gain_max": float(np.max(np.abs(W))),
            **lam_info,
        }
        return y_d, extra


def _on_grid(f_grid: np.ndarray, values: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """A response known on ``f_grid``; other grids get linear interpolation of re and im."""

    def response(f: np.ndarray) -> np.ndarray:
        if f.shape == f_grid.shape and np.allclose(f, f_grid, rtol=0, atol=1e-9 * f_grid[-1]):
            return values
        return np.interp(f, f_grid, values.real) + 1j * np.interp(f, f_grid, values.imag)

    return response


@hookimpl
def mbus_compensators():
    return [CompensatorSpec("transfer_function", TransferFunctionCompensator, TransferFunctionCompensator.summary)]


__all__ = [
    "TransferFunctionCompensator",
    "TransferFunctionOptions",
    "SpectralFilter",
    "coloured_noise_standard_errors",
    "estimate_noise_std",
]
