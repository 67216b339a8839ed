"""report.html: self-contained (figures inline SVG by default, PNG data URIs that decode with
``output.figures: png``, no external resource), the summary tables, warnings in plain words, the
figures; opened in a real headless Chromium when one is installed. The residual correlations are checked against statsmodels."""
from __future__ import annotations

import base64
import html as std_html
import json
import os
import shutil
import struct
import subprocess
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from mbus_framework.cli import main
from mbus_framework.pipeline import html
from mbus_framework.pipeline.figures import confidence_bound, correlation

REPO = Path(__file__).resolve().parents[1]
RECORDED = REPO / "configs" / "recorded.yaml"
FIGURE_COUNT = 6  # fit, residual correlation, frequency response, excitation, convergence, dispersion


class Page(HTMLParser):
    """Tags, attributes and text of an HTML document."""

    def __init__(self, text: str):
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.text: list[str] = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.text.append(data)

    def all(self, tag: str) -> list[dict[str, str]]:
        return [a for t, a in self.tags if t == tag]

    @property
    def plain(self) -> str:
        return " ".join(self.text)


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def assert_self_contained(page: Page) -> None:
    assert not page.all("script") and not page.all("link") and not page.all("iframe")
    for tag, attrs in page.tags:
        for key in ("src", "href"):
            value = attrs.get(key)
            if value is not None:
                assert value.startswith(("data:image/png;base64,", "#")), (tag, key, value[:60])


@pytest.fixture(scope="module")
def plotted_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report") / "run"
    assert main([str(RECORDED), "-o", str(out), "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def png_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report_png") / "run"
    assert main([str(RECORDED), "-o", str(out), "-q", "--set", "output.figures=png"]) == 0
    return out


def test_report_holds_the_svg_figures_inline(plotted_run):
    """The default figures: one inline ``<svg>`` per figure, each the run folder's .svg file
    (valid XML), no image data URI; result.json names the .svg files."""
    text = (plotted_run / "report.html").read_text(encoding="utf-8")
    page = Page(text)
    assert_self_contained(page)
    assert page.all("img") == [] and "data:image" not in text
    assert len(page.all("svg")) == FIGURE_COUNT
    result = json.loads((plotted_run / "result.json").read_text())
    assert not list(plotted_run.glob("*.png"))
    for key in ("fit_plot", "correlation_plot", "frequency_response_plot", "excitation_plot", "convergence_plot",
                "dispersion_plot"):
        svg = (plotted_run / result["files"][key]).read_text(encoding="utf-8")
        assert result["files"][key].endswith(".svg") and svg.startswith("<svg")
        root = ET.fromstring(svg)
        assert root.tag == "{http://www.w3.org/2000/svg}svg" and int(root.get("width")) >= 500
        assert svg[4:] in text  # the same drawing, inline
    assert len(page.all("table")) >= 5 and "Measured and predicted output" in page.plain


def test_report_is_self_contained_with_figures_and_tables(png_run):
    plotted_run = png_run
    text = (plotted_run / "report.html").read_text(encoding="utf-8")
    page = Page(text)
    assert_self_contained(page)
    images = page.all("img")
    assert len(images) == FIGURE_COUNT
    for img in images:
        png = base64.b64decode(img["src"].split(",", 1)[1], validate=True)
        width, height = png_size(png)
        assert width >= 500 and height >= 300, img["alt"]
    assert len(page.all("table")) >= 5  # properties, parameters, fit quality, correlation, excitation
    for words in ("Material properties", "E_sigma", "Pa s", "nrmse", "No warnings", "Fit quality",
                  "autocorrelation", "frequency response", "Config", "kelvin_voigt", "report.html"):
        assert words in page.plain, words
    result = json.loads((plotted_run / "result.json").read_text())
    assert result["files"]["report"] == "report.html"
    for key in ("fit_plot", "correlation_plot", "frequency_response_plot", "excitation_plot", "convergence_plot"):
        assert (plotted_run / result["files"][key]).read_bytes()[:4] == b"\x89PNG", key


def test_report_without_plots_keeps_the_tables(tmp_path):
    assert main([str(RECORDED), "-o", str(tmp_path / "run"), "-q", "--no-plots"]) == 0
    page = Page((tmp_path / "run" / "report.html").read_text(encoding="utf-8"))
    assert_self_contained(page)
    assert page.all("img") == [] and page.all("svg") == [] and "Figures were not drawn" in page.plain
    assert len(page.all("table")) >= 5
    assert not list((tmp_path / "run").glob("*.png")) and not list((tmp_path / "run").glob("*.svg"))


def test_warnings_are_listed_in_plain_words(tmp_path):
    """A design that cannot be the recorded excitation: each warning is one list item."""
    assert main([str(RECORDED), "-o", str(tmp_path / "run"), "-q", "--no-plots", "--set",
                 "excitation={name: prbs, options: {order: 9, bit_width: 2.5e-6, sample_rate: 6.25e6}}"]) == 0
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert len(result["warnings"]) >= 3
    text = (tmp_path / "run" / "report.html").read_text(encoding="utf-8")
    items = [std_html.unescape(chunk.split("</li>")[0]) for chunk in text.split("<li>")[1:]]
    assert items == result["warnings"]
    plain = Page(text).plain
    assert "Warnings" in plain and "No warnings" not in plain


# ---------------------------------------------------------------------------------------
# The primitives
# ---------------------------------------------------------------------------------------
def test_primitives_escape_text_and_format_numbers():
    warn = html.warnings(["<script>alert(1)</script> & more"])
    assert "<script>" not in warn and "&lt;script&gt;" in warn
    table = html.table([["a<b", 1.23456789, float("inf"), float("nan"), 3, True]], header=["x", "y", "z", "w", "n", "b"])
    page = Page(table)
    assert page.plain.split() == ["x", "y", "z", "w", "n", "b", "a<b", "1.2346", "inf", "nan", "3", "True"]
    assert [a.get("class") for t, a in page.tags if t == "td"] == [None, "num", "num", "num", "num", None]
    section = html.section("S & T", html.paragraph("p"), "raw <b>", anchor="s")
    assert section.startswith('<section id="s"><h2>S &amp; T</h2><p>p</p>raw &lt;b&gt;')


def test_figure_is_a_png_data_uri():
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 3))
    fig.subplots().plot([0, 1], [1, 0])
    block = html.figure(fig, alt="line", caption="a line")
    img = Page(block).all("img")[0]
    assert png_size(base64.b64decode(img["src"].split(",", 1)[1])) == (400, 300)
    assert img["alt"] == "line" and "a line" in Page(block).plain
    doc = html.page("t", [block], subtitle="s", nav=[("x", "X")])
    assert doc.startswith("<!DOCTYPE html>") and doc.count("<style>") == 1
    assert_self_contained(Page(doc))


# ---------------------------------------------------------------------------------------
# Residual correlations (what MATLAB's resid shows)
# ---------------------------------------------------------------------------------------
def test_correlations_equal_statsmodels():
    from statsmodels.tsa.stattools import acf, ccf

    rng = np.random.default_rng(4)
    a = rng.normal(size=700).cumsum() * 0.1 + rng.normal(size=700)
    b = np.convolve(a, [0.5, 0.3, 0.2], mode="same") + rng.normal(size=700)
    k, r = correlation(a, a, 20)
    np.testing.assert_allclose(r[k >= 0], acf(a, nlags=20, fft=False), rtol=0, atol=1e-12)
    k, r = correlation(a, b, 20)
    # statsmodels: ccf(x, y)[j] = corr(x_(t+j), y_t); ours: r_ab(k) = corr(a_t, b_(t+k)).
    np.testing.assert_allclose(r[k >= 0], ccf(b, a, adjusted=False)[:21], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r[k <= 0][::-1], ccf(a, b, adjusted=False)[:21], rtol=0, atol=1e-12)


def test_confidence_band_holds_for_white_residuals():
    """99 % of a white series' autocorrelations stay inside z_0.995 / sqrt(N): binomial check."""
    rng = np.random.default_rng(8)
    n, lags, series = 2000, 25, 200
    bound = confidence_bound(n)
    assert bound == pytest.approx(stats.norm.ppf(0.995) / np.sqrt(n))
    outside = 0
    for _ in range(series):
        k, r = correlation(x := rng.normal(size=n), x, lags)
        outside += int(np.sum(np.abs(r[k >= 1]) > bound))
    test = stats.binomtest(outside, series * lags, 0.01)
    assert test.pvalue > 1e-3, (outside, series * lags)


# ---------------------------------------------------------------------------------------
# A real browser, when one is installed
# ---------------------------------------------------------------------------------------
def chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


BROWSER_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]


@pytest.mark.skipif(chromium() is None, reason="no Chromium installed (apt-get install chromium)")
def test_report_opens_in_headless_chromium(plotted_run, tmp_path):
    """Chromium parses the page (images and tables in its DOM) and paints the figures: the
    screenshot of the figures' section shows the model's red curve."""
    url = (plotted_run / "report.html").resolve().as_uri()
    env = dict(os.environ, HOME=str(tmp_path))
    common = [chromium(), *BROWSER_FLAGS, f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run([*common, "--dump-dom", url], capture_output=True, text=True, timeout=120, env=env)
    assert dom.returncode == 0, dom.stderr[-2000:]
    page = Page(dom.stdout)
    assert len(page.all("svg")) == FIGURE_COUNT and len(page.all("table")) >= 5
    shot = tmp_path / "report.png"
    subprocess.run([*common, "--window-size=1200,6000", f"--screenshot={shot}", url], capture_output=True,
                   timeout=120, env=env, check=True)
    from matplotlib.image import imread

    pixels = imread(shot)[..., :3]
    red = (pixels[..., 0] > 0.7) & (pixels[..., 1] < 0.35) & (pixels[..., 2] < 0.35)  # matplotlib C3
    assert red.sum() > 500, red.sum()


def assert_folder_report(folder: Path, figures: int, *texts: str) -> Page:
    """``folder/report.html`` of a study, comparison, design or calibration: self-contained,
    the printed summary, ``figures`` embedded PNGs (every PNG of the folder), the config."""
    page = Page((folder / "report.html").read_text(encoding="utf-8"))
    assert_self_contained(page)
    imgs = page.all("img")
    assert len(imgs) == figures == len(list(folder.glob("*.png")))
    for img in imgs:
        assert png_size(base64.b64decode(img["src"].split(",", 1)[1]))[0] > 100
    for text in texts:
        assert text in page.plain, text
    return page


def test_folder_report_embeds_the_summary_figures_and_config(tmp_path):
    from mbus_framework.pipeline.folder_report import write_folder_report
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3, 2))
    fig.add_subplot().plot([0, 1], [1, 0])
    (tmp_path / "b_plot.png").write_bytes(html.png_bytes(fig))
    (tmp_path / "a_plot.png").write_bytes(html.png_bytes(fig))
    (tmp_path / "config.yaml").write_text("sample: {length: 0.03}\n")
    write_folder_report(tmp_path, "mbus study: monte carlo", "  k_sigma <1 % & ok\n")
    page = assert_folder_report(tmp_path, 2, "k_sigma <1 % & ok", "length: 0.03", "mbus study: monte carlo")
    assert [i["alt"] for i in page.all("img")] == ["a plot", "b plot"]
