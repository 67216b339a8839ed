"""The figures of a run drawn by matplotlib (PNG output and notebooks).

What each figure shows is built once by :mod:`~mbus_framework.pipeline.figure_spec`; this
module draws a spec with matplotlib (:func:`draw`), the SVG renderer
(:mod:`~mbus_framework.pipeline.svg`, a run's default) draws the same spec without it. Each
function takes a :class:`FitData` and returns a matplotlib ``Figure`` on an Agg canvas (no pyplot
state, so runs in a loop leak nothing); pass ``fig`` to draw into a figure of your own (e.g. one
made by ``matplotlib.pyplot.figure()`` in a notebook).

* :func:`fit_figure`: measured vs predicted output and the residual (Fig. 3.9);
* :func:`correlation_figure`: residual autocorrelation and input-residual cross-correlation with
  their confidence band, as MATLAB's ``resid`` shows them;
* :func:`frequency_response_figure`: measured vs model frequency response (H1 estimates);
* :func:`excitation_figure`: power spectrum of the fitted input, and of the design (Fig. 3.7);
* :func:`convergence_figure`: parameters and cost per iteration of the winning start (Fig. 3.8);
* :func:`dispersion_figure`: phase velocity and attenuation of the fitted material.
"""
from __future__ import annotations

import re
from pathlib import PurePath
from typing import TYPE_CHECKING, Any

from mbus_framework.pipeline.figure_spec import (  # noqa: F401 - public names of this module
    LAGS, LEVEL, SPECS, FigureSpec, FitData, Panel, confidence_bound, convergence_spec, correlation,
    correlation_spec, dispersion_spec, excitation_spec, fit_spec, frequency_response_spec, shown_band, wrap)

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

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


def wrapped(fig: "Figure", text: str, fontsize: float = 12.0, share: float = 0.95) -> str:
    """``text`` broken into lines that fit ``share`` of the figure's width (:func:`wrap`)."""
    return wrap(text, fig.get_figwidth(), fontsize, share)


def _draw_item(ax: Any, it: Any) -> None:
    kw = {"color": it.color, "alpha": it.alpha} if it.alpha != 1.0 else {"color": it.color}
    if it.kind == "line":
        ax.plot(it.x, it.y, lw=it.width, label=it.label, **kw, **({"marker": "."} if it.marker else {}))
    elif it.kind == "markers":
        ax.plot(it.x, it.y, ".", ms=it.size, label=it.label, **kw)
    elif it.kind == "stems":
        ax.vlines(it.x, 0, it.y, **kw)
        ax.plot(it.x, it.y, "o", ms=it.size, label=it.label, **kw)
    elif it.kind == "band":
        ax.fill_between(it.x, it.y, it.y2, lw=0, label=it.label, **kw)
    elif it.kind == "hspan":
        ax.axhspan(*it.y, lw=0, label=it.label, **kw)
    elif it.kind == "vspan":
        ax.axvspan(*it.x, lw=0, label=it.label, **kw)
    elif it.kind == "hline":
        ax.axhline(it.y, lw=it.width, **kw)
    elif it.kind == "vline":
        ax.axvline(it.x, lw=it.width, **kw)
    else:
        raise ValueError(f"unknown figure item {it.kind!r}")


def _draw_panel(ax: Any, p: Panel) -> None:
    ax.set_xscale(p.xscale)
    ax.set_yscale(p.yscale)
    for it in p.items:
        _draw_item(ax, it)
    if p.note:
        ax.text(0.5, 0.5, p.note, ha="center", transform=ax.transAxes)
    if p.xlim:
        ax.set_xlim(*p.xlim)
    if p.ylim:
        ax.set_ylim(*p.ylim)
    if p.xlabel:
        ax.set_xlabel(p.xlabel)
    if p.ylabel:
        ax.set_ylabel(p.ylabel)
    if p.title:
        ax.set_title(p.title, fontsize=p.title_size)
    if p.grid:
        ax.grid(True, alpha=p.grid)
    if p.legend and p.items and any(it.label for it in p.items):
        ax.legend(loc=p.legend, fontsize=p.legend_size)
    if p.yscale == "linear":
        ax.ticklabel_format(axis="y", style="plain", useOffset=False)
    _plain_log_ticks(ax)


def draw(spec: FigureSpec, fig: "Figure | None" = None) -> "Figure":
    """Draw ``spec`` with matplotlib (into ``fig``, or a new figure on an Agg canvas)."""
    fig = _new(fig, spec.size)
    n = len(spec.panels)
    rows, cols = (n, 1) if spec.layout == "rows" else (1, n)
    kw = {"gridspec_kw": {"height_ratios": spec.ratios}} if spec.ratios else {}
    axes = fig.subplots(rows, cols, sharex=spec.sharex, squeeze=False, **kw).ravel()
    for ax, p in zip(axes, spec.panels):
        _draw_panel(ax, p)
    if spec.suptitle:
        fig.suptitle(spec.suptitle)
    adjust = spec.adjust()
    if spec.layout == "rows":
        adjust.pop("wspace")
    else:
        adjust.pop("hspace")
    fig.subplots_adjust(**adjust)
    return fig


def fit_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Measured vs predicted output, and the residual (Fig. 3.9; :func:`~mbus_framework.pipeline.figure_spec.fit_spec`)."""
    return draw(fit_spec(d), fig)


def correlation_figure(d: FitData, fig: "Figure | None" = None, lags: int = LAGS, level: float = LEVEL) -> "Figure":
    """Residual autocorrelation and input-residual cross-correlation with the ``level`` band
    (MATLAB ``resid``; :func:`~mbus_framework.pipeline.figure_spec.correlation_spec`)."""
    return draw(correlation_spec(d, lags, level), fig)


def frequency_response_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Measured vs model frequency response (H1 estimates; :func:`~mbus_framework.pipeline.figure_spec.frequency_response_spec`)."""
    return draw(frequency_response_spec(d), fig)


def excitation_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Power spectrum of the fitted input and of the design (Fig. 3.7; :func:`~mbus_framework.pipeline.figure_spec.excitation_spec`)."""
    return draw(excitation_spec(d), fig)


def convergence_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Parameters and cost per iteration of the winning start (Fig. 3.8; :func:`~mbus_framework.pipeline.figure_spec.convergence_spec`)."""
    return draw(convergence_spec(d), fig)


def dispersion_figure(d: FitData, fig: "Figure | None" = None) -> "Figure":
    """Phase velocity and attenuation with 95 % bands (:func:`~mbus_framework.pipeline.figure_spec.dispersion_spec`)."""
    return draw(dispersion_spec(d), fig)


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


def file_name(name: str, fmt: str = "png") -> str:
    """The run folder's file of figure ``name`` in format ``fmt`` (``png`` or ``svg``): ``fit.svg``."""
    return str(PurePath(FIGURES[name][1]).with_suffix("." + fmt))


def render_svg(d: FitData, names: list[str] | None = None) -> dict[str, bytes]:
    """SVG (UTF-8 bytes, :mod:`~mbus_framework.pipeline.svg`) of every figure that applies (or
    of ``names``); no matplotlib."""
    from mbus_framework.pipeline.svg import render

    return {name: render(SPECS[name](d), name).encode("utf-8") for name in (applicable(d) if names is None else names)}


def render_all(d: FitData, dpi: int = 100, names: list[str] | None = None) -> dict[str, bytes]:
    """PNG bytes of every figure that applies (or of ``names``)."""
    from mbus_framework.pipeline.html import png_bytes

    return {name: png_bytes(FIGURES[name][0](d), dpi) for name in (applicable(d) if names is None else names)}
