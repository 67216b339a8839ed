"""Every figure kind, drawn and checked as an image: each axis label carries a unit ("[...]"
or "(...)"), no offset text ("x1e10") beside a label, every text inside the canvas, no axis
label over another panel. Figures of a potato run, a compensated run, an element sweep, a model
comparison, a campaign and an excitation design are caught at ``savefig`` (every writer of the
package saves through it) and checked there."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.text import Text

from mbus_framework.pipeline.figures import FIGURES, FitData, fit_figure
from mbus_framework.pipeline.report import write_figures
from mbus_framework.pipeline.run import execute
from mbus_framework.pipeline.units import UNKNOWN, record_units, scaled_unit

REPO = Path(__file__).resolve().parents[1]
SMALL = REPO / "tests" / "data" / "studies_small.yaml"
UNIT = re.compile(r"\[[^\]]+\]|\([^)]+\)")
FAST = ["model.options.n_elements=4", "excitation.options.n_samples=1500", "solver.options.strategy.n_starts=2"]


def layout_problems(fig: Figure) -> list[str]:
    """What is wrong with ``fig`` as drawn: labels without units, offset texts, texts outside
    the canvas, a y label over another panel."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    out = []
    axes = [ax for ax in fig.axes if ax.get_visible() and ax.axison]
    ticks = set()
    for ax in axes:
        for axis in (ax.xaxis, ax.yaxis):
            ticks.update(map(id, axis.get_ticklabels(which="both")))
            label = axis.get_label().get_text()
            if label and not UNIT.search(label):
                out.append(f"label without a unit: {label!r}")
            if axis.get_offset_text().get_visible() and axis.get_offset_text().get_text():
                out.append(f"offset text {axis.get_offset_text().get_text()!r} beside {label!r}")
        if not ax.get_ylabel():
            out.append(f"axes {ax.get_title()!r} without a y label")
    if axes and not any(ax.get_xlabel() for ax in axes):
        out.append("no x label")
    for t in fig.findobj(Text):
        if id(t) in ticks or not t.get_visible() or not t.get_text().strip():
            continue
        b = t.get_window_extent(r)
        if b.x0 < -1 or b.y0 < -1 or b.x1 > W + 1 or b.y1 > H + 1:
            out.append(f"text {t.get_text()[:40]!r} outside the figure ({b.x0:.0f}, {b.y0:.0f}, {b.x1:.0f}, {b.y1:.0f})")
    tight = fig.get_tightbbox(r)
    if tight.x0 < -0.01 or tight.y0 < -0.01 or tight.x1 > fig.get_figwidth() + 0.01 or tight.y1 > fig.get_figheight() + 0.01:
        out.append(f"tight bbox {tight} beyond the figure")
    for ax in axes:
        label = ax.yaxis.get_label()
        if not label.get_text():
            continue
        lb = label.get_window_extent(r)
        for other in axes:
            if other is not ax and lb.overlaps(other.get_window_extent(r)):
                out.append(f"y label {label.get_text()!r} overlaps another panel")
    return out


@pytest.fixture
def saved(monkeypatch):
    """Every figure saved while the test runs: (name, problems)."""
    seen: list[tuple[str, list[str]]] = []
    original = Figure.savefig

    def checked(self, fname, *args, **kwargs):
        name = Path(fname).name if isinstance(fname, (str, Path)) else (self._suptitle.get_text() if self._suptitle
                                                                       else self.axes[0].get_title())
        seen.append((name, layout_problems(self)))
        return original(self, fname, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", checked)
    return seen


def assert_clean(seen: list[tuple[str, list[str]]], at_least: int) -> None:
    assert len(seen) >= at_least, [n for n, _ in seen]
    bad = {name: p for name, p in seen if p}
    assert not bad, bad


def run_figures(outcome) -> list[tuple[str, list[str]]]:
    d = outcome.fit_data()
    return [(name, layout_problems(build(d))) for name, (build, *_rest) in FIGURES.items()
            if not ((name == "convergence" and not d.trace) or (name == "dispersion" and not d.dispersion))]


def test_potato_run_figures_have_units_and_stay_inside(tmp_path):
    outcome = execute(REPO / "configs" / "potato.yaml", FAST, tmp_path / "run", plots=False)
    assert outcome.result["record_units"] == {"u": "N", "y": "N", "y_band_limited": False}
    found = run_figures(outcome)
    assert {n for n, _ in found} == set(FIGURES)
    assert_clean(found, len(FIGURES))
    fig = fit_figure(outcome.fit_data())
    assert re.fullmatch(r"output y \[[pnumkMG]?N\]", fig.axes[0].get_ylabel())
    assert re.fullmatch(r"residual \[[pnumkMG]?N\]", fig.axes[1].get_ylabel())
    assert fig.axes[0].get_title() == "potato slice (Table 6.2 truth), simulated rig: measured vs predicted output"


def test_compensated_run_in_volts_is_band_limited_and_its_title_is_whole(tmp_path):
    from mbus_framework.studies.transducer_calibration import run_calibration

    cal = tmp_path / "pair.npz"
    run_calibration(REPO / "configs" / "water_calibration.yaml", [f"calibration.output={cal}", "output.plots=false"],
                    tmp_path / "cal")
    outcome = execute(REPO / "configs" / "potato_compensated.yaml",
                      [f"compensator.options.calibration={cal}", *FAST[:1], FAST[2]], tmp_path / "run", plots=False)
    assert outcome.result["record_units"] == {"u": "V", "y": "V", "y_band_limited": True}
    assert_clean(run_figures(outcome), 5)
    fig = fit_figure(outcome.fit_data())
    ax = fig.axes[0]
    assert re.fullmatch(r"output y \[[pnumkMG]?V\]", ax.get_ylabel())
    assert ax.get_title().replace("\n", " ").endswith("measured vs predicted output (band-limited)")
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["measured, band-limited", "model, band-limited"]
    # the files written by a run pass through the same check
    pngs, _ = write_figures(tmp_path / "run", outcome.fit_data())
    assert "fit_plot" in pngs


def test_volts_record_from_a_file_header_and_unknown_units():
    assert record_units({"units": {"u": "V", "y": "mV"}}) == {"u": "V", "y": "mV", "y_band_limited": False}
    assert record_units({"source": "data.csv"})["y"] == UNKNOWN
    assert record_units({"shots_averaged": 8, "u_gain": 1.0, "y_gain": 2.5}) == {"u": "V", "y": "N",
                                                                                "y_band_limited": False}
    # deconvolution divides the transducer pair out: the output is in the input's unit
    comp = {"name": "transfer_function", "mode": "deconvolve"}
    assert record_units({"units": {"u": "N", "y": "V"}}, comp)["y"] == "N"
    t = np.arange(64) * 1e-7
    d = FitData(t, np.sin(t * 1e6), 5 * np.cos(t * 1e6), 4.5 * np.cos(t * 1e6), units={"u": "V", "y": "V"})
    assert fit_figure(d).axes[0].get_ylabel() == "output y [V]"
    assert fit_figure(d).axes[1].get_ylabel() == "residual [mV]"  # 0.5 cos: a median below 1 V
    d.units = {}
    fig = fit_figure(d)
    assert fig.axes[0].get_ylabel() == "output y (recorded units)"
    assert not layout_problems(fig)


def test_scaled_units():
    assert scaled_unit([2.4e10, 2.5e10], "Pa") == (1e9, "GPa")
    assert scaled_unit([7.2e3], "Pa s") == (1e3, "kPa s")
    assert scaled_unit([3e-6], "s") == pytest.approx((1e-6, "us"))
    assert scaled_unit([5.0], "Pa") == (1.0, "Pa")
    assert scaled_unit([2e10], "") == (1e9, "1e9")
    assert scaled_unit([1080.0], "kg/m^3") == (1e3, "1e3 kg/m^3")


def test_element_sweep_figure_in_gigapascal():
    """The sweep's panels from estimates of order 1e10 Pa: GPa on the axis, no "x1e10"."""
    from mbus_framework.studies.element_sweep import _sweep_figure

    ok = [{"n_elements": n, "properties": {"E_sigma": 2.4e10 * (1 + 0.1 / n), "eta_sigma": 7.2e3 * (1 - 0.1 / n)},
           "property_standard_errors": {"E_sigma": 1e8, "eta_sigma": 50.0}} for n in (2, 4, 8)]
    fig = _sweep_figure(ok, ["E_sigma", "eta_sigma"], {"E_sigma": 2.4e10}, {"E_sigma": 4},
                        {"E_sigma": "Pa", "eta_sigma": "Pa s"})
    assert [ax.get_ylabel() for ax in fig.axes[:2]] == ["E_sigma [GPa]", "eta_sigma [kPa s]"]
    np.testing.assert_allclose(fig.axes[0].lines[0].get_ydata(), [24 * (1 + 0.1 / n) for n in (2, 4, 8)])
    assert not layout_problems(fig)


@pytest.mark.slow
def test_element_sweep_figure(tmp_path, saved):
    from mbus_framework.studies.runner import run_study

    run_study("element_sweep", SMALL, [], tmp_path / "sweep", n_values=[3, 4], reference_n=5, tolerance=0.5,
              warm_start=False)
    sweep = [(n, p) for n, p in saved if n.startswith("Material properties against the number of elements")]
    assert_clean(sweep, 1)
    assert_clean(saved, 1)


def test_comparison_bode_is_limited_to_the_excited_band(tmp_path, saved):
    import yaml

    from mbus_framework.studies.compare import run_comparison

    cfg = yaml.safe_load(SMALL.read_text())
    cfg["output"] = {"directory": str(tmp_path / "runs"), "plots": True}
    cfg["solver"] = {"name": "scipy_lm", "options": {"strategy": {"n_starts": 1}}}
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    run_comparison(path, ["kelvin_voigt", "maxwell"], [], out_dir=tmp_path / "cmp")
    bode = [(n, p) for n, p in saved if n == "comparison_bode.png"]
    assert_clean(bode, 1)


def test_bode_axes_stay_in_the_band():
    from mbus_framework.engine.control_interop import bode_figure
    from mbus_framework.estimation.spectral import excited_band
    from mbus_framework.interfaces.sample import Sample
    from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

    model = KelvinVoigtChain(Sample(0.05, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=4))
    theta = np.array([p.typical for p in model.parameters])
    rng = np.random.default_rng(1)
    dt = 1.6e-7
    u = np.repeat(rng.choice([-1.0, 1.0], 128), 16)  # PRBS-like, power below ~0.4 / (16 dt)
    from mbus_framework.engine.simulation import simulate

    y = simulate(model, theta, u, dt, "zoh") + 1e-3 * rng.normal(size=u.size)
    band = excited_band(u, dt)
    fig = bode_figure(model, theta, u, y, dt, band=band, units=("N", "N"))
    for line in fig.axes[0].get_lines():
        x = np.asarray(line.get_xdata(), float)
        assert x.min() >= band[0] / 1e6 * (1 - 1e-9) and x.max() <= band[1] / 1e6 * (1 + 1e-9)
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "measured (H1 estimate)" in legend
    assert fig.axes[0].get_ylabel() == "|H| [dB re 1 N/N]" and fig.axes[1].get_xlabel() == "frequency [MHz]"
    assert not layout_problems(fig)


def test_campaign_plots_carry_units(tmp_path, saved):
    from mbus_framework.campaigns.plan import plan_campaign
    from mbus_framework.campaigns.report import group_report
    from mbus_framework.campaigns.spec import load_campaign
    from mbus_framework.campaigns.table import build_table

    units = plan_campaign(load_campaign(REPO / "configs" / "campaigns" / "liquids.yaml"), tmp_path / "plan")[0].units
    assert units["E_sigma"] == "Pa" and units["eta_sigma"] == "Pa s"
    rng = np.random.default_rng(2)
    rows = []
    for i in range(6):
        row = {"sample_id": f"s{i}", "material": "abc"[i % 3], "replicate": None, "replicates": "averaged",
               "n_replicates": 1, "nrmse": 0.03, "success": True, "warnings": None, "error": None,
               "run_dir": f"runs/s{i}", "fit_time_s": 0.1}
        for p, scale in (("E_sigma", 2.4e10), ("eta_sigma", 7e3)):
            v = scale * rng.uniform(0.9, 1.1)
            row.update({p: v, f"{p}_se": 0.02 * v, f"{p}_ci_low": 0.96 * v, f"{p}_ci_high": 1.04 * v})
        rows.append(row)
    report = group_report(build_table(rows, ["material"], []), ["material"], tmp_path,
                          title="a campaign with a long title that would otherwise run off the figure's edge",
                          units=units)
    assert sorted(report.plots) == ["E_sigma", "eta_sigma"]
    assert_clean(saved, 2)


def test_design_without_transducers_shades_no_transducer_band(tmp_path, saved, monkeypatch):
    import matplotlib.axes

    from mbus_framework.studies.design import band_label, run_design

    spans = []
    original = matplotlib.axes.Axes.axvspan
    monkeypatch.setattr(matplotlib.axes.Axes, "axvspan",
                        lambda self, *a, **k: spans.append(k.get("label")) or original(self, *a, **k))
    text = run_design(REPO / "configs" / "potato.yaml", FAST[1:2], tmp_path / "design")
    assert "no transducers" in text
    assert spans == ["design band (default; no transducers)"]
    assert_clean(saved, 1)
    assert band_label("default design band (no transducers in the config)") == "design band (default; no transducers)"
    assert band_label("the rig's transducer pair (-6 dB)") == "transducer band"
    assert band_label("design.band") == "design.band"


def test_frequency_response_figure_stops_where_record_and_model_say_nothing():
    """The shown band is the coherent band around the model's peak widened 1.5x (a lone coherent
    noise point beyond it does not extend it, one incoherent bin inside does not end it), and
    above at most twice where the model falls 60 dB below its peak."""
    from mbus_framework.pipeline.figures import shown_band

    f = np.linspace(0.0, 10e6, 101)
    mag = np.exp(-f / 1e6)  # peak at 0; falls 60 dB (1e-3) at ln(1000) MHz = 6.9 MHz
    coherence = np.where(f <= 2e6, 0.9, 0.1)
    assert shown_band(f, mag, coherence) == pytest.approx((0.0, 3e6))  # 1.5 x 2 MHz
    coherence[60] = 0.7  # a lone coherent point at 6 MHz
    coherence[10] = 0.3  # one incoherent bin at 1 MHz
    assert shown_band(f, mag, coherence) == pytest.approx((0.0, 3e6))
    assert shown_band(f, mag, np.full_like(f, 0.9)) == pytest.approx((0.0, 2 * 6.9e6))
    assert shown_band(f, np.zeros_like(f), coherence) is None
    # a band-pass record (a compensated one): incoherent below 3 MHz, peak at 5 MHz
    bandpass = np.exp(-(((f - 5e6) / 1e6) ** 2))
    coh = np.where((f >= 3e6) & (f <= 7e6), 0.9, 0.05)
    lo, hi = shown_band(f, bandpass, coh)
    assert lo == pytest.approx(3e6 / 1.5) and hi == pytest.approx(min(1.5 * 7e6, 2 * f[bandpass >= 1e-3][-1]))
