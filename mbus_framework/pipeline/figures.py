"""The figures of a run, drawn from the fitted record and the model's prediction.

Each function takes a :class:`FitData` and returns a matplotlib ``Figure`` on an Agg canvas
(no pyplot state, so runs in a loop leak nothing); pass ``fig`` to draw into a figure of your
own (e.g. one made by ``matplotlib.pyplot.figure()`` in a notebook).

* :func:`fit_figure`: measured vs predicted output and the residual (Fig. 3.9);
* :func:`correlation_figure`: residual autocorrelation and input-residual cross-correlation with
  their confidence band, as MATLAB's ``resid`` shows them;
* :func:`frequency_response_figure`: measured vs model frequency response (H1 estimates);
* :func:`excitation_figure`: power spectrum of the fitted input, and of the design (Fig. 3.7);
* :func:`convergence_figure`: parameters and cost per iteration of the winning start (Fig. 3.8).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import TYPE_CHECKING, Any

import numpy as np

from mbus_framework.engine.control_interop import transfer_function_estimate
from mbus_framework.engine.moving import moving_average
from mbus_framework.interfaces.waveform import Waveform, power_spectrum
from mbus_framework.pipeline.recorded_input import welch_spectrum
from mbus_framework.pipeline.units import UNKNOWN, label_axis

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from mbus_framework.estimation.problem import FitProblem, FitResult

#: Lags shown in the correlation plots (MATLAB's ``resid`` default).
LAGS = 25
#: Level of the correlation confidence band (MATLAB's ``resid`` default: 99 %).
LEVEL = 0.99


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
        only the :data:`BEFORE_FIT` figures can be drawn from it (the same as after the fit)."""
        return cls(problem.t, problem.u, problem.y, np.full_like(problem.y, np.nan, dtype=float), designed=designed)

    @classmethod
    def from_fit(cls, problem: "FitProblem", fit: "FitResult", designed: Waveform | None = None,
                 title: str = "", dispersion: dict[str, Any] | None = None,
                 units: dict[str, Any] | None = None) -> "FitData":
        return cls(problem.t, problem.u, problem.y, problem.y - fit.residuals, list(fit.names),
                   list(fit.trace), designed, title, dispersion, dict(units or {}))


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
    so that the figure helpers need not import scipy.special)."""
    return float(NormalDist().inv_cdf(0.5 + level / 2) / np.sqrt(n))


def _new(fig: "Figure | None", size: tuple[float, float]) -> "Figure":
    if fig is not None:
        return fig
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig


#: Exponent digits as Unicode superscripts (DejaVu Sans has them): "10⁻¹" without mathtext.
_SUPERSCRIPT = str.maketrans("0123456789-", "\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b")
_MATH = re.compile(r"\$\\mathdefault\{(.*)\}\$")


def plain_log_label(label: str) -> str:
    """A log-axis tick label of matplotlib's ``LogFormatterSciNotation`` (``$\\mathdefault{10^{-1}}$``,
    ``$\\mathdefault{2\\times10^{3}}$``) as plain text (``10⁻¹``, ``2×10³``): the same label,
    without the mathtext parser (about a fifth of the drawing time of a log axis)."""
    m = _MATH.fullmatch(label)
    if not m:
        return label
    body = m.group(1).replace("\\times", "\u00d7")
    return re.sub(r"\^\{([^}]*)\}", lambda g: g.group(1).translate(_SUPERSCRIPT), body)


def _plain_log_ticks(*axes: Any) -> None:
    """Plain-text labels (:func:`plain_log_label`) on the log-scaled axes of ``axes``; ticks,
    base and which ticks are labelled stay matplotlib's."""
    from matplotlib.ticker import LogFormatterSciNotation

    class PlainLogFormatter(LogFormatterSciNotation):
        def __call__(self, x: float, pos: int | None = None) -> str:
            return plain_log_label(super().__call__(x, pos))

    for ax in axes:
        for axis in (ax.xaxis, ax.yaxis):
            for major in (True, False):
                old = axis.get_major_formatter() if major else axis.get_minor_formatter()
                if type(old) is LogFormatterSciNotation:
                    new = PlainLogFormatter(old._base, labelOnlyBase=old.labelOnlyBase,
                                            minor_thresholds=old.minor_thresholds, linthresh=old._linthresh)
                    (axis.set_major_formatter if major else axis.set_minor_formatter)(new)


def _margins(fig: "Figure", **kw: float) -> None:
    """Fixed margins: ``tight_layout`` costs more than drawing the figure (log-axis ticks)."""
    fig.subplots_adjust(**{"left": 0.09, "right": 0.98, "top": 0.93, "bottom": 0.1, "hspace": 0.35, **kw})


def wrapped(fig: "Figure", text: str, fontsize: float = 12.0, share: float = 0.95) -> str:
    """``text`` broken into lines that fit ``share`` of the figure's width (a character is
    about 0.55 font sizes wide), so titles are never cut at the canvas edge."""
    import textwrap

    width = max(20, int(share * fig.get_figwidth() * 72 / (0.55 * fontsize)))
    return "\n".join(textwrap.wrap(text, width)) or text


def fit_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Measured vs predicted output, and the residual (Fig. 3.9), in the record's output unit;
    a compensated output is marked band-limited (the fit sees it through the compensator's band)."""
    fig = _new(fig, (9, 6))
    ax1, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    t_us = d.t * 1e6
    band = ", band-limited" if d.band_limited else ""
    k = label_axis(ax1, "y", "output y", d.y, d.y_unit)
    ax1.plot(t_us, d.y / k, lw=0.7, color="0.55", label=f"measured{band}")
    ax1.plot(t_us, d.yhat / k, lw=0.9, color="C3", label=f"model{band}")
    ax1.legend(loc="upper right")
    what = "measured vs predicted output" + (" (band-limited)" if d.band_limited else "")
    title = wrapped(fig, f"{d.title}: {what}" if d.title else what)
    ax1.set_title(title)
    k = label_axis(ax2, "y", "residual", d.residuals, d.y_unit)
    ax2.plot(t_us, d.residuals / k, lw=0.6, color="C0")
    ax2.set_xlabel("time [us]")
    _margins(fig, hspace=0.08, left=0.1, top=0.93 - 0.035 * title.count("\n"))
    return fig


def correlation_figure(d: FitData, fig: "Figure | None" = None, lags: int = LAGS, level: float = LEVEL) -> "Figure":
    """Residual autocorrelation (lags 0..``lags``) and input-residual cross-correlation
    (-``lags``..``lags``) with the ``level`` band +-z/sqrt(N): bars outside it mean the residual
    is not white or still depends on the input (MATLAB ``resid``)."""
    fig = _new(fig, (9, 5.5))
    ax1, ax2 = fig.subplots(2, 1)
    e = d.residuals
    bound = confidence_bound(e.size, level)
    k, r = correlation(e, e, lags)
    keep = k >= 1  # r(0) = 1 by definition; leaving it out keeps the band readable
    ax1.vlines(k[keep], 0, r[keep], color="C0")
    ax1.plot(k[keep], r[keep], "o", ms=3, color="C0")
    ku, ru = correlation(d.u, e, lags)
    ax2.vlines(ku, 0, ru, color="C2")
    ax2.plot(ku, ru, "o", ms=3, color="C2")
    for ax, lo, vals in ((ax1, 1, r[keep]), (ax2, -lags, ru)):
        ax.axhspan(-bound, bound, color="C1", alpha=0.18, lw=0, label=f"{100 * level:g} % band, white residual")
        ax.axhline(0, color="0.3", lw=0.6)
        ax.set_xlim(lo - 0.5, lags + 0.5)
        top = 1.25 * max(2 * bound, float(np.max(np.abs(vals))) if vals.size else 0.0)
        ax.set_ylim(-top, top)
    ax1.set_title("autocorrelation of the residual (lags 1-%d; r(0) = 1)" % lags)
    ax1.set_ylabel("r_ee(k) [-]")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.set_title("cross-correlation of input and residual")
    ax2.set_ylabel("r_ue(k) [-]")
    ax2.set_xlabel("lag k [samples]")
    _margins(fig, hspace=0.45)
    return fig


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


def frequency_response_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Measured vs model frequency response: H1 = P_uy / P_uu of the record and of the model's
    prediction, by the same estimator (Welch, a quarter of the record per segment), so both carry
    the same windowing; measured points with coherence below 0.5 are faded. Shown up to
    :func:`shown_band`: outside it neither the record nor the model says anything."""
    fig = _new(fig, (9, 6))
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)
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
    for mask, alpha, label in ((good, 0.9, "measured (H1 estimate)"), (~good, 0.25, "measured, coherence < 0.5")):
        if np.any(mask):
            ax_m.semilogx(f_mhz[mask], mag_m[mask], ".", ms=3, color="0.35", alpha=alpha, label=label)
            ax_p.semilogx(f_mhz[mask], phase_m[mask], ".", ms=3, color="0.35", alpha=alpha)
    ax_m.semilogx(f_mhz, mag_p, lw=1.3, color="C3", label="model")
    ax_p.semilogx(f_mhz, phase_p, lw=1.3, color="C3")
    if np.any(good):
        top = float(np.nanmax(mag_m[good]))
        ax_m.set_ylim(top - 80, top + 10)
    per = f"{d.y_unit}/{d.u_unit}"
    ax_m.set_ylabel(f"|H| [dB re 1 {per}]" if UNKNOWN not in (d.y_unit, d.u_unit) else "|H| [dB]")
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("frequency [MHz]")
    for ax in (ax_m, ax_p):
        ax.grid(True, alpha=0.3)
    ax_m.legend(loc="lower left", fontsize=8)
    ax_m.set_title("frequency response: output per input")
    _plain_log_ticks(ax_m, ax_p)
    _margins(fig, hspace=0.08)
    return fig


def excitation_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Power spectrum of the fitted input (Welch) and, with a design, the designed excitation's
    periodogram (Fig. 3.7), each relative to its peak; the input's -3 dB band is marked."""
    fig = _new(fig, (8, 4.2))
    ax = fig.subplots()

    def db(p: np.ndarray) -> np.ndarray:
        return 10 * np.log10(np.maximum(p / p.max(), 1e-12)) if p.max() > 0 else np.full(p.size, -120.0)

    if d.designed is not None:
        spec = power_spectrum(d.designed.u, d.designed.dt)
        keep = spec.f > 0
        ax.semilogx(spec.f[keep] / 1e6, db(spec.power[keep]), lw=0.6, color="0.6", label="designed (periodogram)")
    rec = welch_spectrum(d.u, d.dt)
    keep = rec.f > 0
    ax.semilogx(rec.f[keep] / 1e6, db(rec.power[keep]), lw=1.2, color="C0", label="fitted input (Welch)")
    lo, hi = rec.band_3db()
    ax.axvspan(max(lo, rec.f[keep][0]) / 1e6, hi / 1e6, color="C0", alpha=0.08,
               label=f"-3 dB band {lo / 1e6:.3g}-{hi / 1e6:.3g} MHz")
    ax.set_xlabel("frequency [MHz]")
    ax.set_ylabel("relative power [dB]")
    ax.set_ylim(-60, 5)
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title("excitation spectrum")
    _plain_log_ticks(ax)
    _margins(fig, top=0.91, bottom=0.12)
    return fig


def convergence_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Parameters (relative to their final values) and cost per iteration of the winning start
    (Fig. 3.8); grey lines separate the continuation stages."""
    fig = _new(fig, (11, 4))
    ax1, ax2 = fig.subplots(1, 2)
    if not d.trace:
        ax1.text(0.5, 0.5, "no trace recorded", ha="center", transform=ax1.transAxes)
        return fig
    theta = np.array([rec["theta"] for rec in d.trace], dtype=float)
    cost = np.array([rec["cost"] for rec in d.trace], dtype=float)
    stages = [rec.get("stage", "") for rec in d.trace]
    final = np.where(theta[-1] != 0, theta[-1], 1.0)
    for i, n in enumerate(d.names[: theta.shape[1]]):
        ax1.plot(theta[:, i] / final[i], marker=".", label=n)
    ax1.set_xlabel("iteration [-]")
    ax1.set_ylabel("parameter / final value [-]")
    ax1.legend(fontsize=8)
    ax2.semilogy(cost, marker=".")
    _plain_log_ticks(ax2)
    for k in range(1, len(stages)):
        if stages[k] != stages[k - 1]:
            for ax in (ax1, ax2):
                ax.axvline(k - 0.5, color="0.8", lw=0.8)
    ax2.set_xlabel("iteration [-]")
    unit = "recorded units" if d.y_unit == UNKNOWN else d.y_unit
    ax2.set_ylabel(f"cost 1/2 sum r^2 [{unit}^2]")
    ax2.set_title("band stages: filtered residual", fontsize=9)
    fig.suptitle("convergence of the winning start (Fig. 3.8); grey lines: continuation stages")
    ax1.ticklabel_format(axis="y", useOffset=False)
    _margins(fig, left=0.085, right=0.985, top=0.86, bottom=0.13, wspace=0.4)
    return fig


def dispersion_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Phase velocity [m/s] and attenuation [dB/cm] of the fitted material against frequency
    [MHz], with 95 % bands from the standard errors."""
    fig = _new(fig, (9.0, 3.6))
    ax1, ax2 = fig.subplots(1, 2)
    s = d.dispersion or {}
    f = np.asarray(s.get("frequency_Hz", []), dtype=float) / 1e6
    for ax, key, label in ((ax1, "phase_velocity", "phase velocity [m/s]"), (ax2, "attenuation", "attenuation [dB/cm]")):
        unit = "_m_s" if key == "phase_velocity" else "_dB_per_cm"
        y = np.asarray(s.get(key + unit, []), dtype=float)
        ax.plot(f, y, color="C0")
        se = s.get(key + "_se" + unit)
        if se is not None:
            se = np.asarray(se, dtype=float)
            ax.fill_between(f, y - 1.96 * se, y + 1.96 * se, color="C0", alpha=0.25, lw=0)
        ax.set_xlabel("frequency [MHz]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle("dispersion of the fitted material (longitudinal plane wave; shaded: 95 % band)")
    _margins(fig, left=0.1, top=0.86, bottom=0.15, wspace=0.35)
    return fig


#: Figure name -> (builder, file name, caption). The run folder's PNGs and report.html use these.
FIGURES = {
    "fit": (fit_figure, "fit.png", "Measured and predicted output, and the residual (Fig. 3.9)."),
    "correlation": (correlation_figure, "residual_correlation.png",
                    "Residual autocorrelation and input-residual cross-correlation; the shaded band is where "
                    "99 % of the correlations of a white residual independent of the input fall."),
    "frequency_response": (frequency_response_figure, "frequency_response.png",
                           "Measured and model frequency response (H1 estimates from the record and from the "
                           "model's prediction); faded points have coherence below 0.5."),
    "excitation": (excitation_figure, "excitation.png", "Power spectrum of the fitted input (and of the design)."),
    "convergence": (convergence_figure, "convergence.png",
                    "Parameters and cost per iteration of the winning start (Fig. 3.8)."),
    "dispersion": (dispersion_figure, "dispersion.png",
                   "Phase velocity and attenuation of the fitted material over the record's band."),
}


#: Figures drawn from the fitted record and the design alone (t, u, designed): the same before the
#: fit as after it (the figure helpers draw them while the run fits).
BEFORE_FIT = ("excitation",)


def applicable(d: FitData) -> list[str]:
    """The figures that apply to ``d``, in :data:`FIGURES` order (no convergence plot without a
    trace, no dispersion plot without a dispersion section)."""
    return [name for name in FIGURES
            if not ((name == "convergence" and not d.trace) or (name == "dispersion" and not d.dispersion))]


def render_all(d: FitData, dpi: int = 100, names: list[str] | None = None) -> dict[str, bytes]:
    """PNG bytes of every figure that applies (or of ``names``)."""
    from mbus_framework.pipeline.html import png_bytes

    return {name: png_bytes(FIGURES[name][0](d), dpi) for name in (applicable(d) if names is None else names)}
