"""The run's SVG figures (issue 24: a run's figures without matplotlib): valid XML, coordinates
that map back to the data, nice ticks inside the limits, an envelope that keeps every column's
extremes, no exception on NaN/inf/empty/constant data, and each of the six figures for a potato
run and for a record without design, trace or dispersion."""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from mbus_framework.pipeline import svg
from mbus_framework.pipeline.figure_spec import SPECS, FigureSpec, FitData, Item, Panel
from mbus_framework.pipeline.figures import FIGURES, applicable, render_svg

REPO = Path(__file__).resolve().parents[1]
NS = "{http://www.w3.org/2000/svg}"
FAST = ["model.options.n_elements=4", "excitation.options.n_samples=1500", "solver.options.strategy.n_starts=2"]


def parse(text: str) -> ET.Element:
    root = ET.fromstring(text)
    assert root.tag == NS + "svg"
    return root


def axes_box(root: ET.Element, i: int = 0) -> tuple[float, float, float, float]:
    rects = [c.find(NS + "rect") for c in root.iter(NS + "clipPath")]
    rect = rects[i]
    x, y, w, h = (float(rect.get(k)) for k in ("x", "y", "width", "height"))
    return x, y, x + w, y + h


def path_points(d: str) -> np.ndarray:
    return np.array([[float(a), float(b)] for a, b in re.findall(r"(-?[\d.]+),(-?[\d.]+)", d)])


def line_paths(root: ET.Element, color: str) -> list[str]:
    return [p.get("d") for p in root.iter(NS + "path") if p.get("stroke") == color and p.get("fill") == "none"
            and "stroke-linecap" not in p.attrib and "H" not in p.get("d") and "V" not in p.get("d")]


@pytest.mark.parametrize("log", [False, True])
def test_plotted_points_map_back_to_the_data_within_half_a_pixel(log):
    """The axes transform, written out here independently: p = x0 + (v - lo) / (hi - lo) (x1 - x0),
    on log10(v) for a log axis, y upwards; every vertex of the drawn path is a data point."""
    rng = np.random.default_rng(3)
    x = np.sort(rng.uniform(1.0, 1000.0, 300)) if log else np.sort(rng.uniform(-5.0, 7.0, 300))
    y = rng.uniform(0.01, 50.0, 300) if log else rng.normal(size=300)
    xlim, ylim = ((0.5, 2000.0), (1e-3, 100.0)) if log else ((-6.0, 8.0), (-5.0, 5.0))
    scale = "log" if log else "linear"
    spec = FigureSpec((6, 4), [Panel([Item("line", x, y, color="#123456")], xscale=scale, yscale=scale,
                                     xlim=xlim, ylim=ylim, xlabel="x [-]", ylabel="y [-]")])
    root = parse(svg.render(spec))
    x0, y0, x1, y1 = axes_box(root)
    f = np.log10 if log else (lambda v: np.asarray(v, dtype=float))
    px = x0 + (f(x) - f(xlim[0])) / (f(xlim[1]) - f(xlim[0])) * (x1 - x0)
    py = y1 - (f(y) - f(ylim[0])) / (f(ylim[1]) - f(ylim[0])) * (y1 - y0)
    (d,) = line_paths(root, "#123456")
    drawn = path_points(d)
    assert drawn.shape == (300, 2)
    assert np.max(np.abs(drawn - np.c_[px, py])) <= 0.5


@pytest.mark.parametrize("log", [False, True])
def test_tick_labels_sit_where_their_values_map(log):
    """Each x tick label's number, mapped through the transform, lands on the label's x."""
    xlim = (0.02, 700.0) if log else (-3.3, 11.7)
    spec = FigureSpec((8, 4), [Panel([Item("line", np.array(xlim), np.array([0.0, 1.0]))], xscale="log" if log else
                                     "linear", xlim=xlim, xlabel="x [-]", ylabel="y [-]")])
    root = parse(svg.render(spec))
    x0, _, x1, y1 = axes_box(root)
    labels = [(float(t.get("x")), t.text) for t in root.iter(NS + "text")
              if t.get("text-anchor") == "middle" and float(t.get("y")) < y1 + 30 and float(t.get("y")) > y1]
    assert len(labels) >= 3
    f = math.log10 if log else float
    for x, text in labels:
        v = float(text)
        assert x == pytest.approx(x0 + (f(v) - f(xlim[0])) / (f(xlim[1]) - f(xlim[0])) * (x1 - x0), abs=0.5), text


def _nice(step: float) -> bool:
    mantissa = step / 10.0 ** math.floor(math.log10(step) + 1e-12)
    return any(abs(mantissa - m) < 1e-6 for m in (1.0, 2.0, 2.5, 5.0, 10.0))


def test_linear_ticks_are_nice_inside_and_cover_the_range():
    rng = np.random.default_rng(11)
    for _ in range(2000):
        lo = rng.normal() * 10.0 ** rng.integers(-8, 9)
        hi = lo + max(abs(rng.normal()) * 10.0 ** rng.integers(-8, 9), 1e-6 * abs(lo))  # floats resolve the step
        most = int(rng.integers(4, 11))
        ticks = svg.linear_ticks(lo, hi, most)
        step = float(np.diff(ticks)[0])
        assert 2 <= ticks.size <= most
        assert np.all(ticks >= lo - 1e-9 * abs(step)) and np.all(ticks <= hi + 1e-9 * abs(step))
        assert np.allclose(np.diff(ticks), step, rtol=1e-6) and _nice(step)
        assert ticks[0] - lo <= step * (1 + 1e-9) and hi - ticks[-1] <= step * (1 + 1e-9)  # cover the range
        labels = [svg.tick_label(float(v), step) for v in ticks]
        assert len(set(labels)) == len(labels)  # distinct: as many decimals as the step needs
        assert all(float(t) == pytest.approx(v, rel=1e-5, abs=1e-3 * step) for t, v in zip(labels, ticks))


def test_log_ticks_are_decades_or_1_2_5_inside_the_limits():
    rng = np.random.default_rng(12)
    for _ in range(2000):
        a = rng.uniform(-12, 12)
        b = a + rng.uniform(0.05, 20)
        lo, hi = 10.0**a, 10.0**b
        major, minor = svg.log_ticks(lo, hi, 8)
        assert major.size >= 2, (lo, hi)
        assert np.all(major >= lo * (1 - 1e-9)) and np.all(major <= hi * (1 + 1e-9))
        assert np.all(minor >= lo * (1 - 1e-9)) and np.all(minor <= hi * (1 + 1e-9))
        if b - a >= 2.2:  # decades, evenly spaced, the first within the first stretch of the range
            e = np.log10(major)
            assert np.allclose(e, np.round(e)) and np.allclose(np.diff(e), np.diff(e)[0])
            assert e[0] - a <= np.diff(e)[0] + 1e-9 and b - e[-1] <= np.diff(e)[0] + 1e-9
    assert [svg.tick_label(v) for v in (0.001, 0.01, 0.1, 1.0, 10.0, 1000.0, 1e4, 2e-5, 0.05)] == [
        "1e-3", "0.01", "0.1", "1", "10", "1000", "1e4", "2e-5", "0.05"]


def test_envelope_keeps_every_column_extreme_and_bounds_the_points():
    rng = np.random.default_rng(5)
    n, width = 200_000, 640.0
    px = np.sort(rng.uniform(0, width, n))
    py = np.cumsum(rng.normal(size=n))
    ex, ey = svg.envelope(px, py)
    assert ex.size <= 4 * (width + 1) and np.all(np.diff(ex) >= 0)
    col, ecol = np.floor(px).astype(int), np.floor(ex).astype(int)
    for c in np.unique(col):
        mine, orig = ey[ecol == c], py[col == c]
        assert mine.min() == orig.min() and mine.max() == orig.max()
        assert mine[0] == orig[0] and mine[-1] == orig[-1]  # columns join where the data do
    # every local extreme of the series at column scale is in the drawn points
    assert set(np.round(ey, 12)) <= set(np.round(py, 12))


def test_a_long_record_gives_a_small_valid_file():
    n = 2_000_000
    t = np.arange(n) * 1e-8
    y = np.sin(2 * np.pi * 3e3 * t) + 0.01 * np.random.default_rng(1).normal(size=n)
    y[123_456] = 50.0  # one spike: it must survive the reduction
    text = svg.render(FigureSpec((9, 4), [Panel([Item("line", t * 1e6, y, color="#abcdef")],
                                                xlabel="t [us]", ylabel="y [-]")]))
    root = parse(text)
    assert len(text) < 200_000
    (d,) = line_paths(root, "#abcdef")
    pts = path_points(d)
    _, y0, _, y1 = axes_box(root)
    assert pts[:, 1].min() == pytest.approx(y0 + 0.05 / 1.1 * (y1 - y0), abs=0.5)  # the spike is the top


@pytest.mark.parametrize("values", [np.array([]), np.full(50, np.nan), np.full(50, np.inf), np.full(50, 3.0),
                                    np.array([1.0, np.nan, np.inf, -np.inf, 2.0, np.nan, 5.0]), np.zeros(40),
                                    np.array([-1.0, -2.0, 0.0])])
@pytest.mark.parametrize("scale", ["linear", "log"])
def test_bad_series_give_a_valid_figure(values, scale):
    x = np.arange(values.size, dtype=float) + 1
    items = [Item("line", x, values, marker=True, label="a"), Item("markers", x, values, label="b"),
             Item("stems", x, values), Item("band", x, values - 1, values + 1, alpha=0.2),
             Item("hspan", y=(np.nan, 1.0)), Item("vline", x=np.inf), Item("hline", y=0.0)]
    spec = FigureSpec((5, 3), [Panel(items, yscale=scale, xscale=scale, legend="upper right", title="t"),
                               Panel([], ylabel="e [-]")], sharex=True)
    root = parse(svg.render(spec))
    for p in root.iter(NS + "path"):
        assert "nan" not in p.get("d") and "inf" not in p.get("d")


def _outcome_data(tmp_path) -> FitData:
    from mbus_framework.pipeline.run import execute

    return execute(REPO / "configs" / "potato.yaml", FAST, tmp_path / "run", plots=False).fit_data()


def _texts(root: ET.Element) -> str:
    return " ".join("".join(t.itertext()) for t in root.iter(NS + "text"))


def test_each_figure_renders_for_a_potato_run_and_a_bare_record(tmp_path):
    d = _outcome_data(tmp_path)
    assert applicable(d) == list(FIGURES)
    svgs = render_svg(d)
    for name, content in svgs.items():
        root = parse(content.decode())
        assert root.find(f".//{NS}path") is not None, name
    ids = [e.get("id") for content in svgs.values() for e in parse(content.decode()).iter() if e.get("id")]
    assert len(ids) == len(set(ids))  # unique on one report page
    assert "measured vs predicted output" in _texts(parse(svgs["fit"].decode()))
    assert "99 % band, white residual" in _texts(parse(svgs["correlation"].decode()))
    # a record without a design, a trace or a dispersion section: every builder still draws
    bare = FitData(d.t, d.u, d.y, d.yhat)
    assert applicable(bare) == ["fit", "correlation", "frequency_response", "excitation"]
    for name, build in SPECS.items():
        root = parse(svg.render(build(bare), name))
        assert root.get("width"), name
    assert "no trace recorded" in _texts(parse(svg.render(SPECS["convergence"](bare))))
    # before the fit the prediction is NaN: the excitation figure is the same, the others still draw
    before = FitData(d.t, d.u, d.y, np.full_like(d.y, np.nan))
    for name, build in SPECS.items():
        parse(svg.render(build(before), name))


def test_png_and_svg_show_the_same_spec(tmp_path):
    """The matplotlib figure and the SVG come from one spec: same titles, labels and legend texts."""
    from mbus_framework.pipeline.figures import draw

    t = np.arange(400) * 1e-7
    d = FitData(t, np.sin(t * 3e6), np.cos(t * 3e6), 0.9 * np.cos(t * 3e6), units={"u": "N", "y": "N"})
    spec = SPECS["fit"](d)
    fig = draw(spec)
    texts = _texts(parse(svg.render(spec)))
    for ax in fig.axes:
        for s in (ax.get_title(), ax.get_ylabel(), ax.get_xlabel()):
            assert s in texts
        if ax.get_legend():
            assert all(tx.get_text() in texts for tx in ax.get_legend().get_texts())


def test_an_unknown_figure_format_is_one_line_naming_the_key(tmp_path, capsys):
    from mbus_framework.cli import main

    assert main([str(REPO / "configs" / "potato.yaml"), "-o", str(tmp_path / "run"), "-q", "--set",
                 "output.figures=jpg"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "output.figures" in err and "svg" in err, err


@pytest.mark.parametrize("lim", [(1.0, 1.0), (2.0, 1.0), (np.nan, 1.0), (-1.0, 10.0), (0.0, np.inf)])
def test_unusable_limits_fall_back_to_the_data(lim):
    x = np.linspace(1.0, 100.0, 50)
    for scale in ("linear", "log"):
        spec = FigureSpec((5, 3), [Panel([Item("line", x, x, color="#222222")], xscale=scale, yscale=scale,
                                         xlim=lim, ylim=lim)])
        root = parse(svg.render(spec))
        (d,) = line_paths(root, "#222222")
        pts = path_points(d)
        x0, y0, x1, y1 = axes_box(root)
        if lim[0] < lim[1] and np.isfinite(lim).all() and (scale == "linear" or lim[0] > 0):
            continue  # a usable range: drawn as given
        assert pts.shape == (50, 2) and np.all((pts[:, 0] >= x0) & (pts[:, 0] <= x1))
        assert np.all((pts[:, 1] >= y0) & (pts[:, 1] <= y1))
