"""The input a run fitted: statistics of the recorded input, and its agreement with the design.

With recorded data (the ``file`` backend) the record holds the input, so a config may leave out
``excitation``; result.json then describes the recorded input. When an excitation is given
with recorded data it is the *design*: it aligns scope channels (GDS-2000 exports, lab run
folders) and is reported beside the recorded input, and :func:`consistency_warnings` checks that
it can be what was recorded (sample rate, length, band).

Spectral figures of a signal u sampled every dt (mean removed, periodogram P(f)):

* ``band_3db_hz``: lowest and highest frequency whose Welch power density is at least half the
  peak density (segments of N/8 samples, at least 64, Hann window);
* ``median_frequency_hz`` / ``f95_hz``: frequencies below which 50 % / 95 % of the power lies.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from mbus_framework.interfaces.waveform import Spectrum, Waveform, crest_factor, power_spectrum

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.interfaces.backend import Measurement

#: Recorded and designed median frequencies may differ by this factor before a warning.
BAND_RATIO = 1.5


def welch_spectrum(u: np.ndarray, dt: float) -> Spectrum:
    """Smoothed one-sided power density [unit^2/Hz]: Welch with segments of N/8 >= 64 samples
    (:mod:`mbus_framework.engine.welch`)."""
    from mbus_framework.engine.welch import power_spectral_density

    u = np.asarray(u, dtype=float)
    return Spectrum(*power_spectral_density(u - u.mean(), dt, int(min(u.size, max(64, u.size // 8)))))


def power_quantile(u: np.ndarray, dt: float, q: float) -> float:
    """Frequency [Hz] below which the fraction ``q`` of the (mean-removed) power lies."""
    spec = power_spectrum(u, dt)
    cum = np.cumsum(spec.power)
    if cum[-1] <= 0:
        return 0.0
    return float(spec.f[min(int(np.searchsorted(cum, q * cum[-1])), spec.f.size - 1)])


def input_statistics(u: np.ndarray, dt: float) -> dict[str, Any]:
    """Level, length and band of a sampled input (see the module docstring)."""
    u = np.asarray(u, dtype=float)
    lo, hi = welch_spectrum(u, dt).band_3db()
    return {
        "sample_rate_hz": 1.0 / dt,
        "n_samples": int(u.size),
        "duration_s": u.size * dt,
        "peak": float(np.max(np.abs(u))) if u.size else 0.0,
        "rms": float(np.sqrt(np.mean(u**2))) if u.size else 0.0,
        "crest_factor": crest_factor(u),
        "band_3db_hz": [lo, hi],
        "median_frequency_hz": power_quantile(u, dt, 0.5),
        "f95_hz": power_quantile(u, dt, 0.95),
    }


def recorded_waveform(m: "Measurement") -> Waveform:
    """The measurement's input as a :class:`Waveform` (what is reported when nothing was designed)."""
    return Waveform(np.asarray(m.t, float), np.asarray(m.u, float), input_statistics(m.u, m.dt))


def excitation_section(name: str | None, designed: Waveform | None, m: "Measurement") -> dict[str, Any]:
    """result.json ``excitation``: the design (name and its figures) when there is one, and
    ``input``, the statistics of the input that was fitted."""
    stats = input_statistics(m.u, m.dt)
    if designed is None:
        return {"name": "recorded", "designed": False, "source": m.meta.get("source", "record"), "input": stats}
    return {"name": name, "designed": True, **designed.info, "input": stats}


def consistency_warnings(designed: Waveform, m: "Measurement") -> list[str]:
    """Plain-language warnings where a designed excitation cannot be what the record holds.

    * sample rate: a record that was not aligned to the design (a t,u,y file) must be sampled
      at the design's rate, else the design describes another signal;
    * length: the record should cover the designed excitation;
    * band: the recorded input's median frequency within x/÷ :data:`BAND_RATIO` of the design's,
      and the record's Nyquist frequency above where 95 % of the design's power lies.
    """
    out: list[str] = []
    fs_d, fs_r = designed.sample_rate, 1.0 / m.dt
    aligned = "lags_samples" in m.meta  # resampled onto the scope's grid by cross-correlation
    if not aligned and abs(fs_d - fs_r) > 1e-6 * fs_d:
        out.append(
            f"excitation: designed at {fs_d / 1e6:.4g} MS/s but the record is sampled at {fs_r / 1e6:.4g} MS/s: "
            f"the excitation section does not describe this record (the fit uses the recorded input)"
        )
    dur_d, dur_r = designed.u.size * designed.dt, m.u.size * m.dt
    if dur_r < dur_d - 0.5 * m.dt - 1e-9 * dur_d:
        out.append(
            f"excitation: the record ({dur_r * 1e6:.4g} us) is shorter than the designed excitation "
            f"({dur_d * 1e6:.4g} us): the end of the excitation and its response are missing"
        )
    f50_d, f50_r = power_quantile(designed.u, designed.dt, 0.5), power_quantile(m.u, m.dt, 0.5)
    if f50_d > 0 and f50_r > 0 and not (1 / BAND_RATIO <= f50_r / f50_d <= BAND_RATIO):
        out.append(
            f"excitation: half the recorded input's power lies below {f50_r / 1e6:.3g} MHz, but below "
            f"{f50_d / 1e6:.3g} MHz for the designed excitation: is this the excitation that was played?"
        )
    f95_d = power_quantile(designed.u, designed.dt, 0.95)
    if fs_r < fs_d and fs_r / 2 < f95_d:
        out.append(
            f"excitation: the record's Nyquist frequency ({fs_r / 2e6:.3g} MHz) is below where 95 % of the "
            f"designed excitation's power lies ({f95_d / 1e6:.3g} MHz): the record under-samples the excitation"
        )
    return out
