"""SVG drawing of a :class:`~mbus_framework.pipeline.figure_spec.FigureSpec`: small, fast and
dependency-free (numpy and the standard library), in the run's own process.

The browser lays out the text, so nothing is measured: a label is estimated 0.6 font sizes wide
per character for the margins. A figure of w x h inches is w*100 x h*100 px (matplotlib's PNG at
dpi 100); a font of s pt is s*100/72 px. Data map to pixels by the axes transform of
:class:`Scale`: p = p0 + (v - lo) / (hi - lo) (p1 - p0), with log10(v) for v on a log axis.
Non-finite values (and v <= 0 on a log axis) leave a gap. Long sorted series are reduced to an
envelope per pixel column (:func:`envelope`): first, lowest, highest and last sample of each
column, so every peak survives and a 2,000,000-sample record costs at most four points a column.
"""
from __future__ import annotations

import math
from html import escape
from typing import Sequence

import numpy as np

from mbus_framework.pipeline.figure_spec import FigureSpec, Item, Panel

#: Pixels per inch of the figure (as matplotlib's PNGs at dpi 100) and per point of a font or line.
DPI = 100.0
PT = DPI / 72.0
#: Font size [pt] of tick labels and axis labels (matplotlib's default 10 pt), and per-character width [em].
FONT, CHAR = 10.0, 0.6
FAMILY = "DejaVu Sans,Verdana,Arial,sans-serif"
#: Autoscale margin, a share of the data range (matplotlib's default).
MARGIN = 0.05


class Scale:
    """The transform of one axis: data ``lo``..``hi`` (``log``: log10 of them) onto pixels ``p0``..``p1``."""

    def __init__(self, lo: float, hi: float, log: bool, p0: float, p1: float) -> None:
        self.lo, self.hi, self.log, self.p0, self.p1 = lo, hi, log, p0, p1
        self.a = math.log10(lo) if log else lo
        b = math.log10(hi) if log else hi
        self.k = (p1 - p0) / (b - self.a) if b != self.a and math.isfinite(b - self.a) else 0.0

    def __call__(self, v: np.ndarray | float) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        if self.log:
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan)
        return self.p0 + (v - self.a) * self.k

    def inverse(self, p: np.ndarray | float) -> np.ndarray:
        v = self.a + (np.asarray(p, dtype=float) - self.p0) / (self.k or 1.0)
        return 10.0**v if self.log else v


def _finite(values: np.ndarray, log: bool) -> np.ndarray:
    v = np.asarray(values, dtype=float).ravel()
    return v[np.isfinite(v) & (v > 0)] if log else v[np.isfinite(v)]


def data_limits(items: Sequence[Item], axis: str, log: bool) -> tuple[float, float] | None:
    """(min, max) of the finite values ``items`` put on ``axis`` ("x" or "y"), or None."""
    found: list[np.ndarray] = []
    for it in items:
        if axis == "x" and it.kind in ("line", "markers", "stems", "band", "vspan", "vline"):
            found.append(_finite(it.x, log))
        elif axis == "y" and it.kind in ("line", "markers", "stems", "band", "hspan", "hline"):
            found.append(_finite(it.y, log))
            if it.kind == "band":
                found.append(_finite(it.y2, log))
            if it.kind == "stems" and not log:
                found.append(np.zeros(1))
    found = [f for f in found if f.size]
    if not found:
        return None
    return float(min(f.min() for f in found)), float(max(f.max() for f in found))


def limits(found: tuple[float, float] | None, log: bool) -> tuple[float, float]:
    """Axis limits around data ``found`` with :data:`MARGIN` (in decades on a log axis); a
    single value or no data get a range of their own."""
    if found is None:
        return (1.0, 10.0) if log else (0.0, 1.0)
    lo, hi = (math.log10(found[0]), math.log10(found[1])) if log else found
    if hi - lo <= 1e-12 * max(abs(lo), abs(hi), 1e-300):
        pad = 0.5 if log else (0.05 * abs(lo) if lo else 0.5)
        lo, hi = lo - pad, hi + pad
    else:
        pad = MARGIN * (hi - lo)
        lo, hi = lo - pad, hi + pad
    if log:
        return 10.0**lo, 10.0**hi
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return (-1e300, 1e300)
    return lo, hi


def linear_ticks(lo: float, hi: float, most: int = 8) -> np.ndarray:
    """Ticks at the multiples of a "nice" step (1, 2, 2.5 or 5 times a power of ten) inside
    [lo, hi], at most ``most`` of them and at least two where the range allows."""
    span = hi - lo
    if not (span > 0 and math.isfinite(span)):
        return np.array([lo])
    raw = span / max(most - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        step = m * mag
        first, last = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
        if last - first + 1 <= most:
            break
    return np.arange(first, last + 1) * step


def log_ticks(lo: float, hi: float, most: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(major, minor) ticks of a log axis inside [lo, hi]: decades (every k-th when there are
    more than ``most``), with 2x and 5x added when fewer than two decades fall inside, and
    nice linear ticks on a range narrower than that; minor ticks at 2..9 x each decade."""
    a, b = math.log10(lo), math.log10(hi)
    decades = np.arange(math.ceil(a - 1e-9), math.floor(b + 1e-9) + 1)
    every = max(1, math.ceil(decades.size / most))
    major = 10.0 ** decades[decades % every == 0] if decades.size else np.zeros(0)
    span = np.arange(math.floor(a), math.ceil(b) + 1)
    minor = (np.arange(2, 10)[None, :] * 10.0 ** span[:, None]).ravel()
    inside = (minor >= lo * (1 - 1e-9)) & (minor <= hi * (1 + 1e-9))
    if decades.size >= 2:
        return major, minor[inside]
    for mults in ((1, 2, 5), (1, 2, 3, 4, 5, 6, 7, 8, 9)):
        ticks = (np.array(mults)[None, :] * 10.0 ** span[:, None]).ravel()
        ticks = ticks[(ticks >= lo * (1 - 1e-9)) & (ticks <= hi * (1 + 1e-9))]
        if ticks.size >= 3 or (mults[-1] == 9 and ticks.size >= 2):
            return ticks, np.zeros(0)
    ticks = linear_ticks(lo, hi, 4)
    return ticks[ticks > 0], np.zeros(0)


def tick_label(v: float, step: float | None = None) -> str:
    """A tick's text: plain decimals, as many as ``step`` (the distance to the next tick) needs;
    without a step (a log axis' 1, 2 or 5 x 10^e ticks) plain from 0.01 to 9000 (``0.05``,
    ``1000``) and ``1e-3``/``2e5`` beyond."""
    if v == 0:
        return "0"
    if step is None:
        e = math.floor(math.log10(abs(v)) + 1e-9)
        if -2 <= e <= 3:
            return f"{v:.{max(0, -e)}f}"
        m = v / 10.0**e
        return f"{m:.3g}e{e}"
    big = max(abs(v), abs(step))
    if big >= 1e6 or abs(step) < 1e-4 * big or abs(step) < 1e-6:
        return f"{v:.{min(15, max(3, 2 + math.ceil(math.log10(big / abs(step)))))}g}"
    dec = max(0, -math.floor(math.log10(abs(step)) + 1e-9))
    if abs(round(step, dec) - step) > 1e-9 * abs(step):
        dec += 1
    text = f"{v:.{dec}f}"
    return "0" if float(text) == 0 else text


def envelope(px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points of a series with ascending pixel x ``px`` that a plot needs: in each pixel
    column (floor(px)) the first, the lowest, the highest and the last sample, in their order."""
    n = px.size
    if n <= 4:
        return px, py
    col = np.floor(px)
    starts = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
    ends = np.r_[starts[1:], n] - 1
    seg = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, n]))
    index = np.arange(n)
    lo = np.minimum.reduceat(py, starts)
    hi = np.maximum.reduceat(py, starts)
    imin = np.minimum.reduceat(np.where(py == lo[seg], index, n), starts)
    imax = np.minimum.reduceat(np.where(py == hi[seg], index, n), starts)
    keep = np.unique(np.r_[starts, ends, imin, imax])
    return px[keep], py[keep]


def _runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the runs of True in ``ok``."""
    edges = np.flatnonzero(np.diff(np.r_[0, ok.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _clamp(p: np.ndarray) -> np.ndarray:
    return np.clip(p, -1e5, 1e5)


def _coords(px: np.ndarray, py: np.ndarray) -> str:
    return " ".join(f"{x:.1f},{y:.1f}" for x, y in zip(_clamp(px).tolist(), _clamp(py).tolist()))


def polyline_path(px: np.ndarray, py: np.ndarray, reduce: bool = True) -> str:
    """Path data ``M x,y L ...`` of a series in pixels, a gap at every non-finite point;
    ascending runs longer than four points a pixel column are reduced by :func:`envelope`."""
    ok = np.isfinite(px) & np.isfinite(py)
    parts = []
    for a, b in _runs(ok):
        x, y = px[a:b], py[a:b]
        if reduce and x.size > 8 and x.size > 4 * (abs(x[-1] - x[0]) + 1) and np.all(np.diff(x) >= 0):
            x, y = envelope(x, y)
        if x.size == 1:
            parts.append(f"M{x[0]:.1f},{y[0]:.1f}h0.01")
        else:
            parts.append("M" + _coords(x, y).replace(" ", "L", 1))
    return " ".join(parts)


def _attrs(it: Item, fill: bool = False) -> str:
    opacity = f' {"fill" if fill else "stroke"}-opacity="{it.alpha:.3g}"' if it.alpha != 1.0 else ""
    if fill:
        return f'fill="{it.color}" stroke="none"{opacity}'
    return f'fill="none" stroke="{it.color}" stroke-width="{it.width * PT:.2f}"{opacity}'


def _dots(px: np.ndarray, py: np.ndarray, it: Item, diameter: float) -> str:
    ok = np.isfinite(px) & np.isfinite(py)
    if not np.any(ok):
        return ""
    d = "".join(f"M{x:.1f},{y:.1f}h0" for x, y in zip(_clamp(px[ok]).tolist(), _clamp(py[ok]).tolist()))
    opacity = f' stroke-opacity="{it.alpha:.3g}"' if it.alpha != 1.0 else ""
    return (f'<path d="{d}" fill="none" stroke="{it.color}" stroke-width="{diameter * PT:.2f}" '
            f'stroke-linecap="round"{opacity}/>')


def _item(it: Item, sx: Scale, sy: Scale, box: tuple[float, float, float, float]) -> str:
    """SVG of one item inside the axes ``box`` (x0, y0, x1, y1) [px]."""
    x0, y0, x1, y1 = box
    if it.kind in ("hspan", "vspan"):
        lo, hi = (sy if it.kind == "hspan" else sx)(np.asarray(it.y if it.kind == "hspan" else it.x, dtype=float))
        if not (np.isfinite(lo) and np.isfinite(hi)):
            return ""
        lo, hi = sorted((float(np.clip(lo, -1e5, 1e5)), float(np.clip(hi, -1e5, 1e5))))
        rect = (x0, lo, x1 - x0, hi - lo) if it.kind == "hspan" else (lo, y0, hi - lo, y1 - y0)
        return '<rect x="%.1f" y="%.1f" width="%.1f" height="%.1f" %s/>' % (*rect, _attrs(it, fill=True))
    if it.kind in ("hline", "vline"):
        p = float((sy if it.kind == "hline" else sx)(float(it.y if it.kind == "hline" else it.x)))
        if not math.isfinite(p):
            return ""
        d = f"M{x0:.1f},{p:.1f}H{x1:.1f}" if it.kind == "hline" else f"M{p:.1f},{y0:.1f}V{y1:.1f}"
        return f'<path d="{d}" {_attrs(it)}/>'
    x, y = np.asarray(it.x, dtype=float).ravel(), np.asarray(it.y, dtype=float).ravel()
    n = min(x.size, y.size)
    px, py = sx(x[:n]), sy(y[:n])
    if it.kind == "band":
        y2 = np.asarray(it.y2, dtype=float).ravel()[:n]
        py2 = sy(y2)
        ok = np.isfinite(px) & np.isfinite(py) & np.isfinite(py2)
        out = []
        for a, b in _runs(ok):
            pts = _coords(np.r_[px[a:b], px[a:b][::-1]], np.r_[py[a:b], py2[a:b][::-1]])
            out.append(f'<polygon points="{pts}" {_attrs(it, fill=True)}/>')
        return "".join(out)
    if it.kind == "line":
        path = polyline_path(px, py)
        out = f'<path d="{path}" {_attrs(it)} stroke-linejoin="round"/>' if path else ""
        return out + (_dots(px, py, it, 3.0) if it.marker else "")
    if it.kind == "markers":
        return _dots(px, py, it, it.size * 0.8)
    if it.kind == "stems":
        base = float(np.clip(sy(0.0), -1e5, 1e5)) if not sy.log else y1
        ok = np.isfinite(px) & np.isfinite(py)
        d = "".join(f"M{a:.1f},{base:.1f}V{b:.1f}" for a, b in zip(px[ok].tolist(), _clamp(py[ok]).tolist()))
        stems = f'<path d="{d}" {_attrs(Item("line", color=it.color, width=1.5, alpha=it.alpha))}/>' if d else ""
        return stems + _dots(px, py, it, it.size)
    raise ValueError(f"unknown figure item {it.kind!r}")


def _text(x: float, y: float, text: str, size: float, anchor: str = "middle", extra: str = "") -> str:
    lines = text.split("\n")
    fs = size * PT
    if len(lines) == 1:
        return (f'<text x="{x:.1f}" y="{y:.1f}" font-size="{fs:.1f}" text-anchor="{anchor}"{extra}>'
                f"{escape(text)}</text>")
    spans = "".join(f'<tspan x="{x:.1f}" dy="{0 if i == 0 else 1.2 * fs:.1f}">{escape(s)}</tspan>'
                    for i, s in enumerate(lines))
    return f'<text x="{x:.1f}" y="{y:.1f}" font-size="{fs:.1f}" text-anchor="{anchor}"{extra}>{spans}</text>'


def _legend(p: Panel, box: tuple[float, float, float, float]) -> str:
    entries = [it for it in p.items if it.label]
    if not p.legend or not entries:
        return ""
    fs = p.legend_size * PT
    row, handle, pad = 1.35 * fs, 2.0 * fs, 0.5 * fs
    width = pad * 3 + handle + CHAR * fs * max(len(it.label or "") for it in entries)
    height = pad * 2 + row * len(entries) - (row - fs)
    x0, y0, x1, y1 = box
    loc = p.legend if p.legend != "best" else "upper right"
    left = x0 + pad if "left" in loc else x1 - pad - width
    top = y1 - pad - height if "lower" in loc else y0 + pad
    out = [f'<g class="legend"><rect x="{left:.1f}" y="{top:.1f}" width="{width:.1f}" height="{height:.1f}" '
           f'fill="white" fill-opacity="0.8" stroke="#cccccc" rx="3"/>']
    for i, it in enumerate(entries):
        cy = top + pad + i * row + 0.5 * fs
        hx = left + pad
        if it.kind in ("hspan", "vspan", "band"):
            out.append(f'<rect x="{hx:.1f}" y="{cy - 0.35 * fs:.1f}" width="{handle:.1f}" height="{0.7 * fs:.1f}" '
                       f'{_attrs(it, fill=True)}/>')
        elif it.kind == "line":
            out.append(f'<path d="M{hx:.1f},{cy:.1f}h{handle:.1f}" {_attrs(it)}/>')
            if it.marker:
                out.append(_dots(np.array([hx + handle / 2]), np.array([cy]), it, 3.0))
        else:
            size = it.size if it.kind == "stems" else max(it.size * 0.8, 3.0)
            out.append(_dots(np.array([hx + handle / 2]), np.array([cy]), it, size))
        out.append(_text(hx + handle + pad, cy + 0.35 * fs, it.label or "", p.legend_size, "start"))
    out.append("</g>")
    return "".join(out)


def _boxes(spec: FigureSpec, width: float, height: float) -> list[tuple[float, float, float, float]]:
    """Pixel boxes (x0, y0, x1, y1) of the panels, as matplotlib's ``subplots_adjust`` places them."""
    m, n = spec.adjust(), len(spec.panels)
    left, right = m["left"] * width, m["right"] * width
    top, bottom = (1 - m["top"]) * height, (1 - m["bottom"]) * height
    if spec.layout == "rows":
        ratios = np.asarray(spec.ratios or [1.0] * n, dtype=float)
        cell = (bottom - top) / (n + m["hspace"] * (n - 1))
        sizes = cell * n * ratios / ratios.sum()
        starts = top + np.r_[0.0, np.cumsum(sizes[:-1] + m["hspace"] * cell)]
        return [(left, float(s), right, float(s + h)) for s, h in zip(starts, sizes)]
    cell = (right - left) / (n + m["wspace"] * (n - 1))
    return [(left + i * cell * (1 + m["wspace"]), top, left + i * cell * (1 + m["wspace"]) + cell, bottom)
            for i in range(n)]


def _axis_ticks(lo: float, hi: float, log: bool, length: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(major ticks, minor ticks, labels) of an axis ``length`` px long."""
    most = int(max(4, min(10, length / 45)))
    if log:
        major, minor = log_ticks(lo, hi, most)
        mantissa = major / 10.0 ** np.floor(np.log10(major) + 1e-9)
        if np.allclose(mantissa, np.round(mantissa), rtol=0, atol=1e-6):  # 1, 2, 5 x 10^e
            return major, minor, [tick_label(float(v)) for v in major]
        ticks = major
    else:
        ticks, minor = linear_ticks(lo, hi, most), np.zeros(0)
    step = float(np.min(np.diff(ticks))) if ticks.size > 1 else (abs(float(ticks[0])) if ticks.size else 1.0)
    return ticks, minor, [tick_label(float(v), step or 1.0) for v in ticks]


def _usable(lim: tuple[float, float], items: Sequence[Item], axis: str, log: bool) -> tuple[float, float]:
    """``lim`` where it is a finite, increasing range (positive on a log axis), else the data's."""
    lo, hi = float(lim[0]), float(lim[1])
    if math.isfinite(lo) and math.isfinite(hi) and hi > lo and (lo > 0 or not log):
        return lo, hi
    return limits(data_limits(items, axis, log), log)


def _panel(p: Panel, box: tuple[float, float, float, float], xlim: tuple[float, float],
           show_x: bool, ident: str) -> str:
    x0, y0, x1, y1 = box
    xlim = _usable(xlim, p.items, "x", p.xscale == "log")
    ylim = _usable(p.ylim or limits(data_limits(p.items, "y", p.yscale == "log"), p.yscale == "log"), p.items, "y",
                   p.yscale == "log")
    sx = Scale(*xlim, p.xscale == "log", x0, x1)
    sy = Scale(*ylim, p.yscale == "log", y1, y0)
    fs = FONT * PT
    out = [f'<rect x="{x0:.1f}" y="{y0:.1f}" width="{x1 - x0:.1f}" height="{y1 - y0:.1f}" fill="white"/>']
    xt, xm, xl = _axis_ticks(*xlim, p.xscale == "log", x1 - x0)
    yt, ym, yl = _axis_ticks(*ylim, p.yscale == "log", y1 - y0)
    ticks, grid = [], []
    for vals, minor, labels, s, horizontal in ((xt, xm, xl, sx, False), (yt, ym, yl, sy, True)):
        for i, v in enumerate(np.r_[vals, minor]):
            q = float(s(v))
            if not math.isfinite(q) or q < min(s.p0, s.p1) - 0.5 or q > max(s.p0, s.p1) + 0.5:
                continue
            size = 3.5 * PT if i < vals.size else 2 * PT
            ticks.append(f"M{x0:.1f},{q:.1f}h{-size:.1f}" if horizontal else f"M{q:.1f},{y1:.1f}v{size:.1f}")
            if i < vals.size:
                if p.grid:
                    grid.append(f"M{x0:.1f},{q:.1f}H{x1:.1f}" if horizontal else f"M{q:.1f},{y0:.1f}V{y1:.1f}")
                if horizontal:
                    out.append(_text(x0 - 3.5 * PT - 3, q + 0.35 * fs, labels[i], FONT, "end"))
                elif show_x:
                    out.append(_text(q, y1 + 3.5 * PT + 2 + 0.8 * fs, labels[i], FONT))
    if grid:
        out.append(f'<path d="{"".join(grid)}" stroke="#b0b0b0" stroke-width="{0.8 * PT:.2f}" '
                   f'stroke-opacity="{p.grid:.3g}" fill="none"/>')
    clip = f"{ident}-clip"
    out.append(f'<clipPath id="{clip}"><rect x="{x0:.1f}" y="{y0:.1f}" width="{x1 - x0:.1f}" '
               f'height="{y1 - y0:.1f}"/></clipPath><g clip-path="url(#{clip})">')
    order = sorted(p.items, key=lambda it: it.kind not in ("hspan", "vspan", "band"))
    out += [_item(it, sx, sy, box) for it in order]
    out.append("</g>")
    if p.note:
        out.append(_text((x0 + x1) / 2, (y0 + y1) / 2, p.note, FONT))
    out.append(f'<path d="{"".join(ticks)}" stroke="black" stroke-width="{0.8 * PT:.2f}" fill="none"/>')
    out.append(f'<rect x="{x0:.1f}" y="{y0:.1f}" width="{x1 - x0:.1f}" height="{y1 - y0:.1f}" fill="none" '
               f'stroke="black" stroke-width="{0.8 * PT:.2f}"/>')
    out.append(_legend(p, box))
    if p.xlabel and show_x:
        out.append(_text((x0 + x1) / 2, y1 + 3.5 * PT + 6 + 1.9 * fs, p.xlabel, FONT))
    if p.ylabel:
        chars = max((len(s) for s in yl), default=1)
        x = x0 - 3.5 * PT - 8 - CHAR * fs * chars - 0.3 * fs
        out.append(_text(x, (y0 + y1) / 2, p.ylabel, FONT, extra=f' transform="rotate(-90 {x:.1f} {(y0 + y1) / 2:.1f})"'))
    if p.title:
        lines = p.title.count("\n")
        out.append(_text((x0 + x1) / 2, y0 - 6 - 1.2 * p.title_size * PT * lines, p.title, p.title_size))
    return "".join(out)


def render(spec: FigureSpec, ident: str = "fig") -> str:
    """The figure as one ``<svg>`` element (valid standalone with its namespace, and inline in
    HTML); ``ident`` prefixes its element ids (unique per figure on a page)."""
    width, height = spec.size[0] * DPI, spec.size[1] * DPI
    boxes = _boxes(spec, width, height)
    xlims = [p.xlim or limits(data_limits(p.items, "x", p.xscale == "log"), p.xscale == "log") for p in spec.panels]
    if spec.sharex and spec.layout == "rows":
        shared = [p for p in spec.panels if not p.xlim]
        found = [data_limits(p.items, "x", p.xscale == "log") for p in shared]
        found = [f for f in found if f is not None]
        if found:
            union = limits((min(f[0] for f in found), max(f[1] for f in found)), spec.panels[0].xscale == "log")
            xlims = [p.xlim or union for p in spec.panels]
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" height="{height:.0f}" '
             f'viewBox="0 0 {width:.0f} {height:.0f}" font-family="{FAMILY}" class="mbus-figure">',
             f'<rect width="{width:.0f}" height="{height:.0f}" fill="white"/>']
    last = len(spec.panels) - 1
    for i, (p, box, xlim) in enumerate(zip(spec.panels, boxes, xlims)):
        show_x = not (spec.sharex and spec.layout == "rows" and i < last)
        parts.append(_panel(p, box, xlim, show_x, f"{ident}-{i}"))
    if spec.suptitle:
        parts.append(_text(width / 2, 0.02 * height + 12 * PT, spec.suptitle, 12.0))
    parts.append("</svg>")
    return "".join(parts)
