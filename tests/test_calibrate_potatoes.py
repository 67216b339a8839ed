"""The virtual potatoes campaign (configs/campaigns/potatoes.yaml) and its calibration (Ch. 6)."""
from __future__ import annotations

import filecmp
import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fakes.campaign_tables import PROPS, schema_table
from mbus_framework.analysis.cli import main
from mbus_framework.analysis.calibrate.regression import fit_line

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = ROOT / "configs" / "campaigns" / "potatoes.yaml"
FOLDER = ROOT / "configs" / "campaigns" / "potatoes"


def _generator():
    spec = importlib.util.spec_from_file_location("make_potatoes", FOLDER / "make_potatoes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", ["potatoes.yaml", "potatoes_uncompensated.yaml"])
def test_every_sample_config_validates(name):
    from mbus_framework.pipeline.components import build_components
    from mbus_framework.pipeline.config import apply_overrides, read_yaml, validate_structure

    path = CAMPAIGN.parent / name
    campaign = read_yaml(path)["campaign"]
    base = read_yaml(path.parent / campaign["base"]) if "base" in campaign else campaign["run"]
    assert ("base" in campaign) != ("run" in campaign)
    sheet = pd.read_csv(path.parent / campaign["samples"])
    assert len(sheet) == 30 and sheet.sample_id.is_unique
    keys = [c for c in sheet.columns if "." in c]
    assert set(sheet.columns) == {"sample_id", *keys, *campaign["groups"], *campaign["covariates"]}
    for _, row in sheet.iterrows():
        data = apply_overrides(base, [f"{k}={row[k]}" for k in keys], where=f"{row.sample_id}")
        source = f"{path}: {row.sample_id}"
        components = build_components(validate_structure(data, source), source)
        truth = components.backend.options.truth
        assert {p: truth[p] for p in PROPS} == {p: row[f"backend.options.truth.{p}"] for p in PROPS}
        assert all(truth[p] > 0 for p in PROPS)


def test_generator_reproduces_the_shipped_files(tmp_path):
    gen = _generator()
    gen.write_campaign(tmp_path)
    for name in ("samples.csv", "conventional.csv"):
        assert filecmp.cmp(tmp_path / name, FOLDER / name, shallow=False), name
    shipped = sorted(p.name for p in (FOLDER / "records").iterdir())
    assert shipped == sorted(p.name for p in (tmp_path / "records").iterdir()) and len(shipped) == 120
    _, mismatch, errors = filecmp.cmpfiles(FOLDER / "records", tmp_path / "records", shipped, shallow=False)
    assert mismatch == [] and errors == []


def test_truth_spans_the_documented_range():
    gen = _generator()
    sheet = pd.read_csv(FOLDER / "samples.csv")
    for prop, (lo, hi) in gen.TRUTH_RANGE.items():
        truth = sheet[f"backend.options.truth.{prop}"]
        assert lo <= truth.min() and truth.max() <= hi, prop
        a, b, x_lo, x_hi = gen.RELATION[prop]
        x = sheet[f"true_conv_{prop}"]
        assert x_lo <= x.min() and x.max() <= x_hi
        assert a + b * x_lo > 0  # the line itself stays positive: the multiplicative scatter keeps truths > 0
    # Table 6.2 "after compensation" SDs follow from Table 6.1 (SD = slope SD_conv / r); the drawn truths'
    # spread is of that size (E_sigma 1.82e10, eta_sigma 8.70e3, E_tau 4.94e9 Pa)
    for prop, sd in (("E_sigma", 1.82e10), ("eta_sigma", 8.70e3), ("E_tau", 4.94e9)):
        assert 0.5 * sd < sheet[f"backend.options.truth.{prop}"].std() < 2.0 * sd, prop


def test_heterogeneity_keeps_the_line_as_the_conditional_mean():
    """E[exp(s Z) / c(s)] = 1 for Z normal truncated at Z_MAX (Monte Carlo against the closed form)."""
    gen = _generator()
    rng = np.random.default_rng(3)
    z = gen.truncated_normal(rng, 400_000)
    assert np.abs(z).max() <= gen.Z_MAX
    for s in (0.2, 0.5, 0.9):
        assert np.mean(np.exp(s * z)) / gen.lognormal_mean(s) == pytest.approx(1.0, abs=3e-3), s


def _mbus_table(rel_se=0.002, seed=0):
    """MBUS estimates of the shipped slices: their truth with a 0.2 % estimation error (as measured
    by mbus-run on the 30 configs: all four properties within 0.25 %)."""
    sheet = pd.read_csv(FOLDER / "samples.csv")
    rng = np.random.default_rng(seed)
    truth = {p: sheet[f"backend.options.truth.{p}"].to_numpy() for p in PROPS}
    estimates = {p: v * (1 + rel_se * rng.standard_normal(v.size)) for p, v in truth.items()}
    return schema_table(sheet.sample_id, estimates, truth, rel_se, length=0.03)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    out = tmp_path_factory.mktemp("potatoes")
    _mbus_table().to_csv(out / "properties.csv", index=False)
    assert main(["calibrate", str(out / "properties.csv"), "--conventional", str(FOLDER / "conventional.csv"),
                 "--no-plots"]) == 0
    return out


def test_calibration_recovers_the_known_relation(calibrated):
    """The true slopes and intercepts of make_potatoes.RELATION lie in the 95 % intervals."""
    gen = _generator()
    reg = pd.read_csv(calibrated / "calibration" / "regression.csv").set_index("property")
    assert list(reg.index) == list(PROPS) and (reg.n == 30).all()
    for prop, (intercept, slope, *_rest) in gen.RELATION.items():
        row = reg.loc[prop]
        assert row.slope_ci_low <= slope <= row.slope_ci_high, prop
        assert row.intercept_ci_low <= intercept <= row.intercept_ci_high, prop
        # Table 6.1 stars every r, but its E_tau r = 0.352 at N = 30 has p = 0.056 (t = 1.99)
        assert row.r_p < (0.1 if prop == "E_tau" else 0.01), prop


def test_numbers_agree_with_statsmodels_and_scipy_run_directly(calibrated):
    import statsmodels.api as sm
    from scipy import stats

    out = calibrated / "calibration"
    conv = pd.read_csv(out / "conventional_samples.csv", dtype={"sample_id": str})
    mbus = pd.read_csv(calibrated / "properties.csv", dtype={"sample_id": str})
    data = mbus.merge(conv, on="sample_id")
    reg = pd.read_csv(out / "regression.csv").set_index("property")
    for prop in PROPS:
        x, y = data[f"conv_{prop}"], data[prop]
        ols = sm.OLS(y, sm.add_constant(x)).fit()
        lin = stats.linregress(x, y)
        row = reg.loc[prop]
        assert row.slope == pytest.approx(lin.slope, rel=1e-10)
        assert row.intercept == pytest.approx(lin.intercept, rel=1e-9)
        assert row.r == pytest.approx(lin.rvalue, rel=1e-10)
        assert row.slope_se == pytest.approx(ols.bse.iloc[1], rel=1e-10)
        assert row.intercept_p == pytest.approx(ols.pvalues.iloc[0], rel=1e-8)
        assert (row.slope_ci_low, row.slope_ci_high) == pytest.approx(tuple(ols.conf_int().iloc[1]), rel=1e-10)
    t62 = pd.read_csv(out / "table_6_2.csv", index_col=[0, 1])
    assert t62.loc[("Conventionally measured", "Mean"), "E_tau"] == pytest.approx(conv.conv_E_tau.mean(), rel=1e-4)


#: Table 6.1 (dissertation): r of MBUS on conventional, N = 30
TABLE_6_1_R = {"uncompensated": {"E_sigma": 0.770, "eta_sigma": 0.645, "E_tau": 0.617, "eta_tau": 0.491},
               "compensated": {"E_sigma": 0.780, "eta_sigma": 0.568, "E_tau": 0.352, "eta_tau": 0.476}}


def test_correlations_are_those_of_table_6_1(calibrated):
    """Through the shipped conventional records (fitted by calibrate) and MBUS estimates of the
    shipped truths, r is Table 6.1's compensated r: the campaign carries its error sources."""
    reg = pd.read_csv(calibrated / "calibration" / "regression.csv").set_index("property")
    for prop, r in TABLE_6_1_R["compensated"].items():
        assert reg.loc[prop, "r"] == pytest.approx(r, abs=0.03), prop
    assert reg.r.idxmin() == "E_tau" and reg.r.idxmax() == "E_sigma"


def test_conventional_values_measure_the_specimens(calibrated):
    """calibrate's conventional values are the specimens' (5 % from the slice's own value x_p)."""
    conv = pd.read_csv(calibrated / "calibration" / "conventional_samples.csv", dtype={"sample_id": str})
    draw = _generator().draw_samples()
    data = conv.merge(draw, on="sample_id")
    assert len(data) == 30 and (data.conv_E_tau_n == 3).all() and (data.conv_E_sigma_n == 1).all()
    for prop, tol in (("E_sigma", 0.002), ("eta_sigma", 0.02), ("E_tau", 0.02), ("eta_tau", 0.02)):
        rel = data[f"conv_{prop}"] / data[f"observed_conv_{prop}"] - 1
        assert rel.abs().max() < tol, prop  # compression: fit noise; rheometer: 1 % point scatter
        spread = data[f"conv_{prop}"] / data[f"true_conv_{prop}"] - 1
        assert 0.01 < spread.std() < 0.1, prop  # the specimens differ from the slice (SPECIMEN_SD)


def test_relation_is_recovered_over_new_draws():
    """Over 150 new draws the 95 % intervals cover the true slope and intercept at least 95 % of
    the time, and the sample r is Table 6.1's (the heterogeneity is sized per draw)."""
    gen = _generator()
    rng = np.random.default_rng(1)
    trials, hits = 150, {p: 0 for p in PROPS}
    for seed in range(trials):
        draw = gen.draw_samples(seed=seed)
        for prop, (intercept, slope, *_rest) in gen.RELATION.items():
            x = draw[f"observed_conv_{prop}"] * (1 + 0.005 * rng.standard_normal(len(draw)))
            fit = fit_line(x, draw[prop] * (1 + 0.002 * rng.standard_normal(len(draw))))
            hits[prop] += (fit.slope_ci_low <= slope <= fit.slope_ci_high
                           and fit.intercept_ci_low <= intercept <= fit.intercept_ci_high)
            assert fit.r == pytest.approx(TABLE_6_1_R["compensated"][prop], abs=0.02), (seed, prop)
    for prop, n in hits.items():
        assert n / trials >= 0.95, (prop, n)


@pytest.mark.slow
def test_campaign_run_recovers_the_relation(tmp_path):
    """End to end once the campaign runner exists: mbus-run the campaign, then calibrate."""
    pytest.importorskip("mbus_framework.campaigns")
    run = subprocess.run([sys.executable, "-m", "mbus_framework.cli", str(CAMPAIGN), "-o", str(tmp_path / "c"),
                          "--no-plots", "-q"], capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    table = next((tmp_path / "c").rglob("properties.csv"))
    assert main(["calibrate", str(table), "--conventional", str(FOLDER / "conventional.csv"), "--no-plots",
                 "--out", str(tmp_path / "cal")]) == 0
    reg = pd.read_csv(tmp_path / "cal" / "regression.csv").set_index("property")
    for prop, (intercept, slope, *_rest) in _generator().RELATION.items():
        assert reg.loc[prop, "slope_ci_low"] <= slope <= reg.loc[prop, "slope_ci_high"], prop
        assert reg.loc[prop, "intercept_ci_low"] <= intercept <= reg.loc[prop, "intercept_ci_high"], prop
        assert reg.loc[prop, "r"] == pytest.approx(TABLE_6_1_R["compensated"][prop], abs=0.2), prop  # issue 28
    shutil.rmtree(tmp_path / "c", ignore_errors=True)


@pytest.mark.slow
def test_uncompensated_fits_through_the_mechanical_pair(tmp_path):
    """Three slices (P01, P02, P04) through the matched, backed mechanical pair without
    compensation (about 20 s CPU each): the record's energy lies below the pair's band, so the
    fitted chain's top mode comes down and its lowest goes up: E_sigma well below the truth
    (opposite to Table 6.2), E_tau and eta_tau above it (the direction of Table 6.2);
    docs/analysis.md has the whole campaign (where P03 and P07 end at another minimum)."""
    from mbus_framework.api import run_config
    from mbus_framework.pipeline.config import read_yaml

    run = read_yaml(CAMPAIGN.parent / "potatoes_uncompensated.yaml")["campaign"]["run"]
    assert run["backend"]["options"]["transducers"]["kind"] == "mechanical"
    assert run["backend"]["options"]["transducers"]["receiver_mount"] == "backing"
    sheet = pd.read_csv(FOLDER / "samples.csv").iloc[[0, 1, 3]]
    for _, row in sheet.iterrows():
        keys = [c for c in sheet.columns if "." in c]
        result = run_config(run, {k: row[k] for k in keys}, tmp_path / row.sample_id, plots=False, progress=False)
        assert float(result.properties["E_sigma"]) < 0.7 * row["backend.options.truth.E_sigma"], row.sample_id
        assert float(result.properties["E_tau"]) > 1.1 * row["backend.options.truth.E_tau"], row.sample_id
        assert float(result.properties["eta_tau"]) > 1.1 * row["backend.options.truth.eta_tau"], row.sample_id
