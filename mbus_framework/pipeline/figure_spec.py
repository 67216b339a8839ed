"""WHAT a run's figures show, apart from HOW they are drawn.

Each ``*_spec(d)`` builder computes a figure's data once (H1 estimates, correlations and their
band, dB spectra, the trace normalised by its final values, dispersion bands) and returns a
:class:`FigureSpec`: panels of :class:`Item` s (lines, markers, stems, bands, spans, reference
lines) with scales, limits, labels, legend and titles. Two renderers draw a spec: the SVG one of
:mod:`~mbus_framework.pipeline.svg` (a run's default, no matplotlib) and the matplotlib one of
:mod:`~mbus_framework.pipeline.figures` (PNG, notebooks). Sizes are in inches and points, as
matplotlib's; colours are hex strings (matplotlib's default cycle).
"""
from __future__ import annotations

import textwrap
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import TYPE_CHECKING, Any

import numpy as np

from mbus_framework.engine.moving import moving_average
from mbus_framework.interfaces.waveform import Waveform
from mbus_framework.pipeline.units import UNKNOWN, bracket, scaled_unit

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.estimation.problem import FitProblem, FitResult

#: Lags shown in the correlation plots (MATLAB's ``resid`` default).
LAGS = 25
#: Level of the correlation confidence band (MATLAB's ``resid`` default: 99 %).
LEVEL = 0.99
#: matplotlib's default colour cycle (C0, C1, ...).
CYCLE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")
C0, C1, C2, C3 = CYCLE[:4]


def grey(level: float) -> str:
    """matplotlib's grey ``"0.55"`` as hex."""
    v = round(255 * level)
    return f"#{v:02x}{v:02x}{v:02x}"


@dataclass
class FitData:
    """The arrays behind a run's figures: times t [s], fitted input u and output y (after any
    compensation), the model's prediction yhat, the parameter names and the convergence trace,
    and the designed excitation when the config had one."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    yhat: np.ndarray
    names: list[str] = field(default_factory=list)
    trace: list[dict[str, Any]] = field(default_factory=list)
    designed: Waveform | None = None
    title: str = ""
    dispersion: dict[str, Any] | None = None  # result.json's ``dispersion`` section
    units: dict[str, Any] = field(default_factory=dict)  # result.json's ``record_units`` section

    @property
    def y_unit(self) -> str:
        return str(self.units.get("y") or UNKNOWN)

    @property
    def u_unit(self) -> str:
        return str(self.units.get("u") or UNKNOWN)

    @property
    def band_limited(self) -> bool:
        return bool(self.units.get("y_band_limited"))

    @property
    def residuals(self) -> np.ndarray:
        return self.y - self.yhat

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @classmethod
    def before_fit(cls, problem: "FitProblem", designed: Waveform | None = None) -> "FitData":
        """The record alone, before the solver runs: the prediction is not known yet (NaN), so
        only the figures that need no fit can be drawn from it (the same as after the fit)."""
        return cls(problem.t, problem.u, problem.y, np.full_like(problem.y, np.nan, dtype=float), designed=designed)

    @classmethod
    def from_fit(cls, problem: "FitProblem", fit: "FitResult", designed: Waveform | None = None,
                 title: str = "", dispersion: dict[str, Any] | None = None,
                 units: dict[str, Any] | None = None) -> "FitData":
        return cls(problem.t, problem.u, problem.y, problem.y - fit.residuals, list(fit.names),
                   list(fit.trace), designed, title, dispersion, dict(units or {}))


@dataclass
class Item:
    """One drawn thing. ``kind``: ``line`` (x, y; ``marker`` draws points on it too), ``markers``
    (x, y), ``stems`` (vertical bars from 0 to y at x, with a point on top), ``band`` (filled
    between y and y2 over x), ``hspan``/``vspan`` (filled between two y or x values across the
    axes), ``hline``/``vline`` (one y or x value across the axes). ``width`` is a line width and
    ``size`` a marker diameter [pt]; ``label`` enters the legend."""

    kind: str
    x: Any = None
    y: Any = None
    y2: Any = None
    color: str = C0
    width: float = 1.5
    alpha: float = 1.0
    size: float = 6.0
    marker: bool = False
    label: str | None = None


@dataclass
class Panel:
    """One axes: items, labels, ``xscale``/``yscale`` (``linear`` or ``log``), limits (None:
    from the data with 5 % margins), ``legend`` position (``upper right``, ``lower left``, ...),
    ``grid`` alpha (0: none), a centred ``note`` instead of data."""

    items: list[Item] = field(default_factory=list)
    xlabel: str = ""
    ylabel: str = ""
    title: str = ""
    title_size: float = 12.0
    xscale: str = "linear"
    yscale: str = "linear"
    xlim: tuple[float, float] | None = None
    ylim: tuple[float, float] | None = None
    legend: str | None = None
    legend_size: float = 10.0
    grid: float = 0.0
    note: str = ""


@dataclass
class FigureSpec:
    """A figure: ``size`` (w, h) [in], panels in ``rows`` or ``cols`` (``ratios``: relative
    heights of rows), ``sharex`` (stacked panels share their x axis; only the lowest is labelled),
    ``suptitle`` and matplotlib ``subplots_adjust`` margins (fractions of the figure)."""

    size: tuple[float, float]
    panels: list[Panel]
    layout: str = "rows"
    sharex: bool = False
    ratios: list[float] | None = None
    suptitle: str = ""
    margins: dict[str, float] = field(default_factory=dict)

    def adjust(self) -> dict[str, float]:
        """The margins with matplotlib-like defaults filled in (left, right, top, bottom, hspace, wspace)."""
        return {"left": 0.09, "right": 0.98, "top": 0.93, "bottom": 0.1, "hspace": 0.35, "wspace": 0.2, **self.margins}


def correlation(a: np.ndarray, b: np.ndarray, lags: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation r_ab(k) = sum_t a_t b_(t+k) / sqrt(sum a^2 sum b^2) of the
    mean-removed signals, for k = -lags..lags (the biased estimator of ``statsmodels`` ``acf``
    and MATLAB ``resid``). Returns (k, r)."""
    a = np.asarray(a, float) - np.mean(a)
    b = np.asarray(b, float) - np.mean(b)
    n = a.size
    size = 1 << int(np.ceil(np.log2(2 * n)))
    full = np.fft.irfft(np.conj(np.fft.rfft(a, size)) * np.fft.rfft(b, size), size)
    k = np.arange(-lags, lags + 1)
    denom = float(np.sqrt((a @ a) * (b @ b)))
    r = full[k % size] / denom if denom > 0 else np.zeros(k.size)
    return k, r


def confidence_bound(n: int, level: float = LEVEL) -> float:
    """Half-width z / sqrt(N) of the band a white residual's correlations stay inside with
    probability ``level`` at each lag (z the standard normal quantile; the standard library's,
    so that the figures need not import scipy.special)."""
    return float(NormalDist().inv_cdf(0.5 + level / 2) / np.sqrt(n))


def shown_band(f: np.ndarray, model_mag: np.ndarray, coherence: np.ndarray,
               smooth: int = 5) -> tuple[float, float] | None:
    """(f_lo, f_hi) [Hz] of the frequency-response figure. The coherent band is the run of
    frequencies around the model's peak where the measured coherence, averaged over ``smooth``
    neighbouring bins (a Welch coherence from few segments scatters bin to bin), stays at least
    0.5; the figure shows it widened by 1.5x on both sides, and above at most twice where the
    model falls 60 dB below its peak. Beyond, the H1 estimate and the model's phase are noise
    (e.g. outside a compensator's band)."""
    if not np.any(model_mag > 0):
        return None
    lo, hi = 0.0, 2 * f[np.flatnonzero(model_mag >= 1e-3 * model_mag.max())[-1]]
    peak = int(np.argmax(model_mag))
    c = moving_average(np.asarray(coherence, dtype=float), min(smooth, coherence.size))
    if c[peak] >= 0.5:
        above = np.flatnonzero(c[peak:] < 0.5)
        below = np.flatnonzero(c[: peak + 1] < 0.5)
        hi = min(hi, 1.5 * f[peak + above[0] - 1] if above.size else hi)
        lo = f[below[-1] + 1] / 1.5 if below.size else 0.0
    return float(lo), float(hi)


def wrap(text: str, width_in: float, fontsize: float = 12.0, share: float = 0.95) -> str:
    """``text`` broken into lines that fit ``share`` of a ``width_in`` [in] wide figure (a
    character is about 0.55 font sizes wide), so titles are never cut at the canvas edge."""
    width = max(20, int(share * width_in * 72 / (0.55 * fontsize)))
    return "\n".join(textwrap.wrap(text, width)) or text


def scaled(name: str, values: np.ndarray, unit: str) -> tuple[float, str]:
    """(factor, axis label ``name [scaled unit]``) of :func:`~mbus_framework.pipeline.units.scaled_unit`."""
    factor, shown = scaled_unit(values, unit)
    return factor, f"{name} {bracket(shown)}"


def fit_spec(d: FitData) -> FigureSpec:
    """Measured vs predicted output, and the residual (Fig. 3.9), in the record's output unit;
    a compensated output is marked band-limited."""
    t_us = d.t * 1e6
    band = ", band-limited" if d.band_limited else ""
    k, ylabel = scaled("output y", d.y, d.y_unit)
    what = "measured vs predicted output" + (" (band-limited)" if d.band_limited else "")
    title = wrap(f"{d.title}: {what}" if d.title else what, 9)
    top = Panel([Item("line", t_us, d.y / k, color=grey(0.55), width=0.7, label=f"measured{band}"),
                 Item("line", t_us, d.yhat / k, color=C3, width=0.9, label=f"model{band}")],
                ylabel=ylabel, title=title, legend="upper right")
    e = d.residuals
    k, ylabel = scaled("residual", e, d.y_unit)
    bottom = Panel([Item("line", t_us, e / k, color=C0, width=0.6)], xlabel="time [us]", ylabel=ylabel)
    return FigureSpec((9, 6), [top, bottom], sharex=True, ratios=[3, 1],
                      margins={"hspace": 0.08, "left": 0.1, "top": 0.93 - 0.035 * title.count("\n")})


def correlation_spec(d: FitData, lags: int = LAGS, level: float = LEVEL) -> FigureSpec:
    """Residual autocorrelation (lags 1..``lags``) and input-residual cross-correlation
    (-``lags``..``lags``) with the ``level`` band +-z/sqrt(N) (MATLAB ``resid``)."""
    e = d.residuals
    bound = confidence_bound(e.size, level)
    k, r = correlation(e, e, lags)
    keep = k >= 1  # r(0) = 1 by definition; leaving it out keeps the band readable
    ku, ru = correlation(d.u, e, lags)
    panels = []
    for ks, vals, lo, color in ((k[keep], r[keep], 1, C0), (ku, ru, -lags, C2)):
        finite = np.abs(vals[np.isfinite(vals)])
        top = 1.25 * max(2 * bound, float(finite.max()) if finite.size else 0.0)
        top = top if np.isfinite(top) and top > 0 else 1.0
        panels.append(Panel([Item("hspan", y=(-bound, bound), color=C1, alpha=0.18,
                                  label=f"{100 * level:g} % band, white residual"),
                             Item("hline", y=0.0, color=grey(0.3), width=0.6),
                             Item("stems", ks, vals, color=color, size=3)],
                            xlim=(lo - 0.5, lags + 0.5), ylim=(-top, top)))
    panels[0].title, panels[0].ylabel = f"autocorrelation of the residual (lags 1-{lags}; r(0) = 1)", "r_ee(k) [-]"
    panels[0].legend, panels[0].legend_size = "upper right", 8
    panels[1].title, panels[1].ylabel = "cross-correlation of input and residual", "r_ue(k) [-]"
    panels[1].xlabel = "lag k [samples]"
    return FigureSpec((9, 5.5), panels, margins={"hspace": 0.45})


def frequency_response_spec(d: FitData) -> FigureSpec:
    """Measured vs model frequency response: H1 = P_uy / P_uu of the record and of the model's
    prediction, by the same estimator (Welch, a quarter of the record per segment), so both carry
    the same windowing; measured points with coherence below 0.5 are faded. Shown over
    :func:`shown_band`: outside it neither the record nor the model says anything."""
    from mbus_framework.engine.control_interop import transfer_function_estimate

    meas = transfer_function_estimate(d.u, d.y, d.dt)
    model = transfer_function_estimate(d.u, d.yhat, d.dt)
    band = shown_band(meas.f, np.abs(model.H), meas.coherence)
    if band is not None:
        meas, model = meas.within(*band), model.within(*band)
    good = meas.coherence >= 0.5
    f_mhz = meas.f / 1e6
    phase_m = np.degrees(np.unwrap(np.angle(meas.H)))
    phase_p = np.degrees(np.unwrap(np.angle(model.H)))
    with np.errstate(divide="ignore"):
        mag_m, mag_p = 20 * np.log10(np.abs(meas.H)), 20 * np.log10(np.abs(model.H))
    per = f"{d.y_unit}/{d.u_unit}"
    mag = Panel(ylabel=f"|H| [dB re 1 {per}]" if UNKNOWN not in (d.y_unit, d.u_unit) else "|H| [dB]",
                title="frequency response: output per input", xscale="log", legend="lower left", legend_size=8,
                grid=0.3)
    phase = Panel(xlabel="frequency [MHz]", ylabel="phase [deg]", xscale="log", grid=0.3)
    for mask, alpha, label in ((good, 0.9, "measured (H1 estimate)"), (~good, 0.25, "measured, coherence < 0.5")):
        if np.any(mask):
            mag.items.append(Item("markers", f_mhz[mask], mag_m[mask], color=grey(0.35), alpha=alpha, size=3,
                                  label=label))
            phase.items.append(Item("markers", f_mhz[mask], phase_m[mask], color=grey(0.35), alpha=alpha, size=3))
    mag.items.append(Item("line", f_mhz, mag_p, color=C3, width=1.3, label="model"))
    phase.items.append(Item("line", f_mhz, phase_p, color=C3, width=1.3))
    if np.any(good) and np.isfinite(np.nanmax(mag_m[good])):
        top = float(np.nanmax(mag_m[good]))
        mag.ylim = (top - 80, top + 10)
    return FigureSpec((9, 6), [mag, phase], sharex=True, margins={"hspace": 0.08})


def _db(p: np.ndarray) -> np.ndarray:
    """10 log10(p / max p) [dB], floored at -120 dB."""
    peak = np.max(p) if p.size else 0.0
    return 10 * np.log10(np.maximum(p / peak, 1e-12)) if peak > 0 else np.full(p.size, -120.0)


def excitation_spec(d: FitData) -> FigureSpec:
    """Power spectrum of the fitted input (Welch) and, with a design, the designed excitation's
    periodogram (Fig. 3.7), each relative to its peak; the input's -3 dB band is marked."""
    from mbus_framework.interfaces.waveform import power_spectrum
    from mbus_framework.pipeline.recorded_input import welch_spectrum

    p = Panel(xlabel="frequency [MHz]", ylabel="relative power [dB]", title="excitation spectrum", xscale="log",
              ylim=(-60, 5), legend="lower left", legend_size=8)
    if d.designed is not None:
        spec = power_spectrum(d.designed.u, d.designed.dt)
        keep = spec.f > 0
        p.items.append(Item("line", spec.f[keep] / 1e6, _db(spec.power[keep]), color=grey(0.6), width=0.6,
                            label="designed (periodogram)"))
    rec = welch_spectrum(d.u, d.dt)
    keep = rec.f > 0
    p.items.append(Item("line", rec.f[keep] / 1e6, _db(rec.power[keep]), color=C0, width=1.2,
                        label="fitted input (Welch)"))
    lo, hi = rec.band_3db()
    p.items.append(Item("vspan", x=(max(lo, rec.f[keep][0]) / 1e6, hi / 1e6), color=C0, alpha=0.08,
                        label=f"-3 dB band {lo / 1e6:.3g}-{hi / 1e6:.3g} MHz"))
    return FigureSpec((8, 4.2), [p], margins={"top": 0.91, "bottom": 0.12})


def convergence_spec(d: FitData) -> FigureSpec:
    """Parameters (relative to their final values) and cost per iteration of the winning start
    (Fig. 3.8); grey lines separate the continuation stages."""
    margins = {"left": 0.085, "right": 0.985, "top": 0.86, "bottom": 0.13, "wspace": 0.4}
    title = "convergence of the winning start (Fig. 3.8); grey lines: continuation stages"
    unit = "recorded units" if d.y_unit == UNKNOWN else d.y_unit
    params = Panel(xlabel="iteration [-]", ylabel="parameter / final value [-]", legend="best", legend_size=8)
    cost_panel = Panel(xlabel="iteration [-]", ylabel=f"cost 1/2 sum r^2 [{unit}^2]", yscale="log",
                       title="band stages: filtered residual", title_size=9)
    if not d.trace:
        params.note = "no trace recorded"
        return FigureSpec((11, 4), [params, cost_panel], layout="cols", suptitle=title, margins=margins)
    theta = np.array([rec["theta"] for rec in d.trace], dtype=float)
    cost = np.array([rec["cost"] for rec in d.trace], dtype=float)
    stages = [rec.get("stage", "") for rec in d.trace]
    final = np.where(theta[-1] != 0, theta[-1], 1.0)
    it = np.arange(len(d.trace), dtype=float)
    for i, n in enumerate(d.names[: theta.shape[1]]):
        params.items.append(Item("line", it, theta[:, i] / final[i], color=CYCLE[i % len(CYCLE)], marker=True,
                                 label=n))
    cost_panel.items.append(Item("line", it, cost, color=C0, marker=True))
    for k in range(1, len(stages)):
        if stages[k] != stages[k - 1]:
            for p in (params, cost_panel):
                p.items.append(Item("vline", x=k - 0.5, color=grey(0.8), width=0.8))
    return FigureSpec((11, 4), [params, cost_panel], layout="cols", suptitle=title, margins=margins)


def dispersion_spec(d: FitData) -> FigureSpec:
    """Phase velocity [m/s] and attenuation [dB/cm] of the fitted material against frequency
    [MHz], with 95 % bands (1.96 standard errors)."""
    s = d.dispersion or {}
    f = np.asarray(s.get("frequency_Hz", []), dtype=float) / 1e6
    panels = []
    for key, label in (("phase_velocity", "phase velocity [m/s]"), ("attenuation", "attenuation [dB/cm]")):
        unit = "_m_s" if key == "phase_velocity" else "_dB_per_cm"
        y = np.asarray(s.get(key + unit, []), dtype=float)
        p = Panel(xlabel="frequency [MHz]", ylabel=label, grid=0.3)
        se = s.get(key + "_se" + unit)
        if se is not None:
            se = np.asarray(se, dtype=float)
            p.items.append(Item("band", f, y - 1.96 * se, y + 1.96 * se, color=C0, alpha=0.25))
        p.items.append(Item("line", f, y, color=C0))
        panels.append(p)
    return FigureSpec((9.0, 3.6), panels, layout="cols",
                      suptitle="dispersion of the fitted material (longitudinal plane wave; shaded: 95 % band)",
                      margins={"left": 0.1, "top": 0.86, "bottom": 0.15, "wspace": 0.35})


#: Figure name -> spec builder, in the order of the run folder's figures.
SPECS = {"fit": fit_spec, "correlation": correlation_spec, "frequency_response": frequency_response_spec,
         "excitation": excitation_spec, "convergence": convergence_spec, "dispersion": dispersion_spec}
