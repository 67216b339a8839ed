"""The Python API: fit arrays in three lines from a fresh session, a notebook display, a DataFrame,
plots, run folders that re-run, and the CLI producing what the API produces."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

import mbus_framework as mbus
from fakes.recording import POTATO, prbs_burst, simulate
from mbus_framework.cli import main
from mbus_framework.errors import ConfigError, DataError

REPO = Path(__file__).resolve().parents[1]
TUY = REPO / "examples" / "recorded" / "potato_tuy.csv"


@pytest.fixture(scope="module")
def record():
    u = prbs_burst(POTATO, POTATO.n_samples)
    t, y = simulate(POTATO, u, seed=3)
    return t, u, y


@pytest.fixture(scope="module")
def result(record):
    t, u, y = record
    return mbus.fit(t, u, y, sample=POTATO.sample, model="kelvin_voigt")


def test_three_lines_in_a_fresh_session_write_nothing(tmp_path):
    """What the README shows: import, read a record, fit; then the notebook display and a table."""
    code = textwrap.dedent(f"""
        import mbus_framework as mbus
        t, u, y = mbus.load_record({str(TUY)!r})
        result = mbus.fit(t, u, y, sample={{"length": 0.03, "diameter": 0.0254, "density": 1080.0}})
        html = result._repr_html_()
        df = result.to_dataframe()
        print(html.count("<table"), len(df), round(df.loc["E_sigma", "estimate"] / 2.42e10, 2))
    """)
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         env={"MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["3", "8", "1.0"]
    assert list(tmp_path.iterdir()) == []  # nothing written without out_dir


def test_fit_recovers_the_truth_with_intervals(result):
    props = result.properties
    for name, truth in POTATO.properties.items():
        e = props[name]
        assert e.ci95[0] <= truth <= e.ci95[1] or abs(e.value - truth) < 3 * e.std_error, name
        assert float(e) == e.value and e.unit in ("Pa", "Pa s")
        assert e.relative_std_error == pytest.approx(e.std_error / e.value)
    assert set(result.parameters) == {"k_sigma", "b_sigma", "k_tau", "b_tau"}
    assert result.success and result.warnings == []
    assert result.fit_quality["nrmse"] == pytest.approx(POTATO.noise, rel=0.1)
    assert result.run_dir is None and result.data is not None
    assert "E_sigma" in repr(result) and "0 warnings" in repr(result)
    assert "E_sigma" in result.summary() and "nrmse" in result.summary()


def test_dataframe_long_and_wide(result):
    df = result.to_dataframe()
    assert list(df.columns) == ["kind", "estimate", "unit", "std_error", "rel_std_error", "ci95_low", "ci95_high",
                                "truth", "fixed"]
    assert list(df.index) == ["k_sigma", "b_sigma", "k_tau", "b_tau", "E_sigma", "eta_sigma", "E_tau", "eta_tau"]
    doc = result.document
    assert df.loc["E_tau", "estimate"] == doc["properties"]["E_tau"]
    assert df.loc["E_tau", "ci95_low"] == doc["uncertainty"]["property_ci95"]["E_tau"][0]
    assert df.loc["b_tau", "std_error"] == doc["uncertainty"]["standard_errors"]["b_tau"]
    assert df["truth"].isna().all() and (df["kind"] == "property").sum() == 4
    wide = result.to_dataframe("wide")
    assert len(wide) == 1
    expected = {"k_sigma", "k_sigma_se", "E_sigma", "E_sigma_se", "E_sigma_ci_low", "E_sigma_ci_high", "nrmse",
                "success", "warnings"}
    assert expected <= set(wide.columns)  # the campaign table's columns (docs/campaign-table.md)
    with pytest.raises(ValueError, match="layout must be"):
        result.to_dataframe("tall")


class _Tags(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)

    def handle_data(self, data):
        self.text.append(data)


def test_notebook_display_is_html_with_tables(result):
    parser = _Tags()
    parser.feed(result._repr_html_())
    assert parser.tags.count("table") == 3
    text = " ".join(parser.text)
    for word in ("E_sigma", "95 % low", "nrmse", "No warnings"):
        assert word in text


def test_plot_methods_draw_the_fitted_arrays(result, record):
    from mbus_framework.pipeline.units import bracket, scaled_unit

    fig = result.plot_fit()
    top = fig.axes[0]
    measured, model = top.lines[0].get_ydata(), top.lines[1].get_ydata()
    # drawn in the labelled (scaled) unit of the record's output
    k, unit = scaled_unit(record[2], result.document["record_units"]["y"])
    assert top.get_ylabel() == f"output y {bracket(unit)}"
    np.testing.assert_array_equal(measured, record[2] / k)
    assert k * np.sqrt(np.mean((measured - model) ** 2)) == pytest.approx(
        result.fit_quality["nrmse"] * np.sqrt(np.mean(record[2] ** 2)), rel=1e-9)
    for method in ("plot_residual_correlation", "plot_frequency_response", "plot_excitation", "plot_convergence"):
        assert getattr(result, method)().axes, method


def test_fit_into_a_folder_that_mbus_run_refits(tmp_path, record, capsys):
    t, u, y = record
    saved = mbus.fit(t, u, y, sample=POTATO.sample, out_dir=tmp_path / "api", plots=False, title="from arrays")
    assert saved.run_dir == tmp_path / "api"
    for name in ("config.yaml", "measurement.csv", "result.json", "report.html"):
        assert (tmp_path / "api" / name).is_file(), name
    assert main([str(tmp_path / "api" / "config.yaml"), "-o", str(tmp_path / "again"), "--no-plots", "-q"]) == 0
    again = json.loads((tmp_path / "again" / "result.json").read_text())
    for name, value in saved.document["parameters"].items():
        assert again["parameters"][name] == pytest.approx(value, rel=1e-6)


def test_run_with_overrides_matches_the_cli(tmp_path, capsys):
    config = REPO / "configs" / "recorded.yaml"
    r = mbus.run_config(config, {"solver.options.strategy.n_starts": 2, "title": "api"}, tmp_path / "api", plots=False)
    assert main([str(config), "-o", str(tmp_path / "cli"), "--no-plots", "-q",
                 "--set", "solver.options.strategy.n_starts=2", "--set", "title=api"]) == 0
    cli = json.loads((tmp_path / "cli" / "result.json").read_text())
    assert r.document["parameters"] == pytest.approx(cli["parameters"], rel=1e-12)
    assert r.document["title"] == "api" and r.run_dir == tmp_path / "api"
    mapping = {"sample": POTATO.sample, "model": {"name": "kelvin_voigt"},
               "backend": {"name": "file", "options": {"path": str(TUY)}}}
    from_mapping = mbus.run_config(mapping, ["solver.options.strategy.n_starts=2", "title=api"], tmp_path / "map",
                            plots=False)
    assert from_mapping.document["parameters"] == pytest.approx(cli["parameters"], rel=1e-12)


def test_result_load_rebuilds_the_figures_arrays(tmp_path):
    r = mbus.run_config(REPO / "configs" / "recorded.yaml", out_dir=tmp_path / "run", plots=False)
    loaded = mbus.Result.load(tmp_path / "run")
    assert loaded.document == json.loads((tmp_path / "run" / "result.json").read_text())
    np.testing.assert_allclose(loaded.data.yhat, r.data.yhat, rtol=0, atol=1e-12 * np.abs(r.data.y).max())
    assert len(loaded.data.trace) == len(r.data.trace) > 0
    assert "<svg" in loaded.report_html() and "<img" not in loaded.report_html()
    assert "<img" in loaded.report_html(figures="png")
    assert "<svg" not in loaded.report_html(plots=False) and "<img" not in loaded.report_html(plots=False)
    with pytest.raises(DataError, match="no result.json"):
        mbus.Result.load(tmp_path)


def test_bad_arrays_and_options_are_one_line_errors(record):
    t, u, y = record
    with pytest.raises(DataError, match=r"^<arrays>: length mismatch \(t 3000, u 3000, y 2999 samples\)$"):
        mbus.fit(t, u, y[:-1], sample=POTATO.sample)
    bad = y.copy()
    bad[7] = np.nan
    with pytest.raises(DataError, match="^<arrays>: column y has 1 non-finite"):
        mbus.fit(t, u, bad, sample=POTATO.sample)
    with pytest.raises(ConfigError, match="^<arrays>: model.options.n_element: unknown key; did you mean 'n_elements'"):
        mbus.fit(t, u, y, sample=POTATO.sample, model_options={"n_element": 4})
    with pytest.raises(ConfigError, match="^<arrays>: sample.density: required key is missing"):
        mbus.fit(t, u, y, sample={"length": 0.03, "diameter": 0.0254})


def test_load_record_reads_every_recorded_format():
    t, u, y = mbus.load_record(TUY)
    assert t.size == 2500 and t[0] == 0.0
    pair = mbus.load_record(REPO / "examples/recorded/A0001CH1.CSV", REPO / "examples/recorded/A0001CH2.CSV")
    assert pair.meta["burst_starts_samples"] == [400] and pair.u.size == 3600
    assert pair.dt == pytest.approx(4e-8)
    with pytest.raises(DataError, match="file not found"):
        mbus.load_record("no/such/file.csv")


def test_importing_the_plugin_api_does_not_load_the_pipeline():
    code = ("import sys, mbus_framework.plugins; "
            "print(any(m.startswith(('mbus_framework.pipeline', 'mbus_framework.api')) for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stderr
    assert mbus.fit is mbus.api.fit and "fit" in dir(mbus)
    assert callable(mbus.run_config)
    with pytest.raises(AttributeError, match="has no attribute 'fitt'"):
        mbus.fitt  # noqa: B018
