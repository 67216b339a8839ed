"""Calibration regressions (Table 6.1), bands, inverse prediction and apply-calibration."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fakes.campaign_tables import mark_failed, schema_table
from mbus_framework.analysis.cli import main
from mbus_framework.analysis.calibrate.property_calibration import PropertyCalibration
from mbus_framework.analysis.calibrate.regression import fit_line
from mbus_framework.errors import DataError


@settings(max_examples=25)
@given(slope=st.floats(-1e4, 1e4).filter(lambda v: abs(v) > 1e-2), intercept=st.floats(-1e6, 1e6),
       noise=st.floats(0.05, 10.0), n=st.integers(4, 60), seed=st.integers(0, 2 ** 31))
def test_fit_line_agrees_with_statsmodels_and_scipy(slope, intercept, noise, n, seed):
    import statsmodels.api as sm
    from scipy import stats

    rng = np.random.default_rng(seed)
    x = rng.uniform(1.0, 100.0, n)
    y = intercept + slope * x + noise * abs(slope) * rng.standard_normal(n)
    fit = fit_line(x, y, level=0.9)
    lin = stats.linregress(x, y)
    ols = sm.OLS(y, sm.add_constant(x)).fit()
    ci = ols.conf_int(alpha=0.1)
    assert fit.slope == pytest.approx(lin.slope, rel=1e-9, abs=1e-12)
    assert fit.intercept == pytest.approx(lin.intercept, rel=1e-9, abs=1e-6 * abs(slope))
    # scipy's standard errors go through sqrt(1 - r^2): a few digits are lost as r -> 1
    assert fit.slope_se == pytest.approx(lin.stderr, rel=1e-6)
    assert fit.intercept_se == pytest.approx(lin.intercept_stderr, rel=1e-6)
    assert fit.r == pytest.approx(lin.rvalue, rel=1e-9, abs=1e-12)
    assert fit.r_p == pytest.approx(lin.pvalue, rel=1e-5, abs=1e-300)
    assert fit.slope_p == pytest.approx(ols.pvalues[1], rel=1e-6, abs=1e-300)
    assert fit.intercept_p == pytest.approx(ols.pvalues[0], rel=1e-6, abs=1e-300)
    assert (fit.slope_ci_low, fit.slope_ci_high) == pytest.approx(tuple(ci[1]), rel=1e-9, abs=1e-12)
    assert fit.slope_t == pytest.approx(ols.tvalues[1], rel=1e-9)


def test_bands_agree_with_statsmodels_get_prediction():
    import statsmodels.api as sm

    rng = np.random.default_rng(1)
    x = rng.uniform(2e6, 5e6, 30)
    y = -1.5e10 + 1.5e4 * x + 4e9 * rng.standard_normal(30)
    fit = fit_line(x, y)
    grid = np.linspace(1e6, 6e6, 9)
    frame = sm.OLS(y, sm.add_constant(x)).fit().get_prediction(sm.add_constant(grid)).summary_frame(alpha=0.05)
    bands = fit.bands(grid)
    np.testing.assert_allclose(bands["mean"], frame["mean"], rtol=1e-10)
    np.testing.assert_allclose(bands["ci_low"], frame["mean_ci_lower"], rtol=1e-9)
    np.testing.assert_allclose(bands["pi_high"], frame["obs_ci_upper"], rtol=1e-9)


def test_inverse_interval_is_where_the_prediction_band_meets_y0():
    """Fieller endpoints: the statsmodels prediction interval at each endpoint has y0 on its edge."""
    import statsmodels.api as sm

    rng = np.random.default_rng(2)
    x = rng.uniform(0, 10, 25)
    y = 3 + 2 * x + rng.standard_normal(25)
    fit = fit_line(x, y)
    y0 = np.array([5.0, 13.0, 24.0])
    x0, low, high = fit.inverse(y0)
    np.testing.assert_allclose(x0, (y0 - fit.intercept) / fit.slope)
    res = sm.OLS(y, sm.add_constant(x)).fit()
    for value, lo, hi in zip(y0, low, high):
        at = res.get_prediction(sm.add_constant(np.array([lo, hi]), has_constant="add")).summary_frame(alpha=0.05)
        assert at["obs_ci_upper"].iloc[0] == pytest.approx(value, rel=1e-9)  # slope > 0: lower x, upper band
        assert at["obs_ci_lower"].iloc[1] == pytest.approx(value, rel=1e-9)
    grid = np.arange(10.0)
    flat = fit_line(grid, (grid - 4.5) ** 2)  # symmetric: the slope is exactly 0
    assert flat.slope == pytest.approx(0, abs=1e-12)
    assert not flat.finite_inverse and np.isinf(flat.inverse([4.0])[1]).all()


def test_inverse_intervals_cover_the_truth_95_percent_of_the_time():
    rng = np.random.default_rng(4)
    hits = 0
    trials = 400
    for _ in range(trials):
        x = rng.uniform(0, 10, 20)
        y = 1 + 0.8 * x + 0.7 * rng.standard_normal(20)
        x_new = rng.uniform(0, 10)
        _, low, high = fit_line(x, y).inverse(1 + 0.8 * x_new + 0.7 * rng.standard_normal())
        hits += bool(low <= x_new <= high)
    assert abs(hits / trials - 0.95) < 0.035  # binomial SD 1.1 %


def _linear_tables(tmp_path, n=30, seed=0):
    """Conventional columns and two MBUS variants, each a known line of the conventional value."""
    rng = np.random.default_rng(seed)
    x = {"E_sigma": rng.uniform(1e6, 5e6, n), "eta_sigma": rng.uniform(1.6e4, 6.9e4, n)}
    comp = {"E_sigma": -1.5e10 + 1.5e4 * x["E_sigma"] + 3e9 * rng.standard_normal(n),
            "eta_sigma": 500 + 0.3 * x["eta_sigma"] + 1e3 * rng.standard_normal(n)}
    unc = {p: 4 * v + 1e3 * rng.standard_normal(n) * v.std() / 1e3 for p, v in comp.items()}
    ids = [f"S{i:02d}" for i in range(n)]
    conv = {f"conv_{p}": v for p, v in x.items()}
    tables = {}
    for name, est in (("uncompensated", unc), ("compensated", comp)):
        t = schema_table(ids, est, extra=conv)
        t.to_csv(tmp_path / f"{name}.csv", index=False)
        tables[name] = t
    return x, tables


def test_before_and_after_compensation_side_by_side(tmp_path, capsys):
    _, tables = _linear_tables(tmp_path)
    both = pd.concat([t.assign(compensation=name) for name, t in tables.items()])
    both.to_csv(tmp_path / "both.csv", index=False)
    assert main(["calibrate", str(tmp_path / "both.csv"), "--no-plots", "--out", str(tmp_path / "a")]) == 0
    assert main(["calibrate", f"uncompensated={tmp_path / 'uncompensated.csv'}",
                 f"compensated={tmp_path / 'compensated.csv'}", "--no-plots", "--out", str(tmp_path / "b")]) == 0
    printed = capsys.readouterr().out
    assert "Table 6.1." in printed and "* Significant at the 0.01 level (N = 30)." in printed
    t61 = pd.read_csv(tmp_path / "a" / "table_6_1.csv", header=[0, 1], index_col=0)
    assert list(t61.columns) == [(v, s) for v in ("uncompensated", "compensated") for s in ("Slope", "Intercept", "r")]
    assert list(t61.index) == ["E_sigma", "eta_sigma"]
    pd.testing.assert_frame_equal(t61, pd.read_csv(tmp_path / "b" / "table_6_1.csv", header=[0, 1], index_col=0))
    reg = pd.read_csv(tmp_path / "a" / "regression.csv").set_index(["variant", "property"])
    for variant, table in tables.items():
        for prop in ("E_sigma", "eta_sigma"):
            fit = fit_line(table[f"conv_{prop}"], table[prop])
            assert reg.loc[(variant, prop), "slope"] == pytest.approx(fit.slope)
            assert t61.loc[prop, (variant, "r")].rstrip("*") == f"{fit.r:.3f}"
    t62 = pd.read_csv(tmp_path / "a" / "table_6_2.csv", index_col=[0, 1])
    assert list(dict.fromkeys(t62.index.get_level_values(0))) == [
        "Conventionally measured", "MBUS uncompensated", "MBUS compensated"]
    conv = tables["compensated"]["conv_E_sigma"]
    assert t62.loc[("Conventionally measured", "Std. Deviation"), "E_sigma"] == pytest.approx(conv.std(), rel=1e-4)
    assert t62.loc[("MBUS compensated", "Minimum"), "eta_sigma"] == pytest.approx(
        tables["compensated"]["eta_sigma"].min(), rel=1e-4)
    assert sorted(p.name for p in (tmp_path / "a").glob("calibration_*.json")) == [
        "calibration_compensated.json", "calibration_report.json", "calibration_uncompensated.json"]


def test_apply_calibration_round_trip(tmp_path, capsys):
    x, tables = _linear_tables(tmp_path, n=40, seed=5)
    assert main(["calibrate", str(tmp_path / "compensated.csv"), "--out", str(tmp_path / "cal")]) == 0
    assert (tmp_path / "cal" / "fig_6_4_E_sigma.png").stat().st_size > 10_000
    cal = PropertyCalibration.load(tmp_path / "cal" / "calibration.json")
    fit = cal.fits["E_sigma"]
    assert fit == fit_line(tables["compensated"].conv_E_sigma, tables["compensated"].E_sigma)  # saved exactly
    # new samples from the same line
    rng = np.random.default_rng(9)
    x_new = rng.uniform(1.2e6, 4.8e6, 300)
    y_new = -1.5e10 + 1.5e4 * x_new + 3e9 * rng.standard_normal(300)
    new = mark_failed(schema_table([f"N{i}" for i in range(300)], {"E_sigma": y_new}), [0])
    new.loc[1, "E_sigma"] = fit.y_max * 1.5
    new.to_csv(tmp_path / "new.csv", index=False)
    assert main(["apply-calibration", str(tmp_path / "new.csv"), "--calibration",
                 str(tmp_path / "cal" / "calibration.json")]) == 0
    out = pd.read_csv(tmp_path / "new_calibrated.csv", keep_default_na=False, na_values=[""])
    assert np.isnan(out.loc[0, "calibrated_E_sigma"])  # failed row left empty
    assert "outside the calibrated MBUS range" in out.loc[1, "calibration_warnings"]
    ok = out.iloc[2:]
    x0, low, high = fit.inverse(y_new[2:])
    np.testing.assert_allclose(ok["calibrated_E_sigma"], (y_new[2:] - fit.intercept) / fit.slope, rtol=1e-9)
    np.testing.assert_allclose(ok["calibrated_E_sigma_pi_low"], low, rtol=1e-9)
    np.testing.assert_allclose(ok["calibrated_E_sigma_pi_high"], high, rtol=1e-9)
    # 95 % on average over calibrations (test above); for this one calibration, roughly so
    covered = (ok["calibrated_E_sigma_pi_low"] <= x_new[2:]) & (x_new[2:] <= ok["calibrated_E_sigma_pi_high"])
    assert 0.85 < covered.mean() <= 1.0
    assert "1 failed rows left empty" in capsys.readouterr().out


def test_replicate_rows_are_averaged_per_sample(tmp_path):
    _, tables = _linear_tables(tmp_path, n=10, seed=3)
    t = tables["compensated"]
    reps = pd.concat([t.assign(replicate=1), t.assign(replicate=2, E_sigma=t.E_sigma * 1.02)])
    reps.to_csv(tmp_path / "reps.csv", index=False)
    assert main(["calibrate", str(tmp_path / "reps.csv"), "--no-plots", "--out", str(tmp_path / "r")]) == 0
    report = json.loads((tmp_path / "r" / "calibration_report.json").read_text())
    assert report["notes"] == ["MBUS: averaged 20 rows into 10 samples"]
    reg = pd.read_csv(tmp_path / "r" / "regression.csv").set_index("property")
    assert reg.loc["E_sigma", "slope"] == pytest.approx(fit_line(t.conv_E_sigma, t.E_sigma * 1.01).slope)


def test_calibrate_errors_are_one_line(tmp_path, capsys):
    _, tables = _linear_tables(tmp_path, n=10)
    plain = tables["compensated"].drop(columns=["conv_E_sigma", "conv_eta_sigma"])
    plain.to_csv(tmp_path / "plain.csv", index=False)
    cases = [
        (["calibrate", str(tmp_path / "plain.csv")], "no conventional values: give --conventional SHEET"),
        (["calibrate", str(tmp_path / "compensated.csv"), "--level", "95"], "--level must be between 0 and 1"),
        (["apply-calibration", str(tmp_path / "plain.csv"), "--calibration", str(tmp_path / "plain.csv")],
         "not a JSON calibration"),
        (["apply-calibration", str(tmp_path / "plain.csv"), "--calibration", str(tmp_path / "none.json")],
         "calibration file not found"),
    ]
    sheet = tmp_path / "conv.csv"
    pd.DataFrame({"sample_id": ["X1"], "test": ["rheometer"], "file": ["x.csv"]}).to_csv(sheet, index=False)
    cases.append((["calibrate", str(tmp_path / "plain.csv"), "--conventional", str(sheet)], "x.csv: file not found"))
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (argv, err)
    (tmp_path / "wrong.json").write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(DataError, match="not an mbus property calibration"):
        PropertyCalibration.load(tmp_path / "wrong.json")
