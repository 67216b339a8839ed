"""Studies (issue 4, item 6): every table statistic is recomputed here from the per-run
result.json files the study leaves behind, independently of mbus_framework.studies."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from mbus_framework.errors import ConfigError
from mbus_framework.studies.common import StudyResult
from mbus_framework.studies.element_sweep import settle_index
from mbus_framework.studies.options import parse_int_list, parse_study_options, validate_study_options
from mbus_framework.studies.runner import run_study

SMALL = Path(__file__).parent / "data" / "studies_small.yaml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class RecordingProgress:
    def __init__(self):
        self.events = []

    def start(self, description, total=None):
        self.events.append(("start", total))

    def advance(self, steps=1, note=""):
        self.events.append(("advance", steps))

    def stop(self):
        self.events.append(("stop", None))


def run_results(study: StudyResult) -> dict[str, dict]:
    """label -> the result.json of that run, read from disk."""
    out = {}
    for d in sorted((study.out_dir / "runs").iterdir()):
        out[d.name] = json.loads((d / "result.json").read_text())
    return out


def run_configs(study: StudyResult) -> dict[str, dict]:
    return {d.name: yaml.safe_load((d / "config.yaml").read_text()) for d in sorted((study.out_dir / "runs").iterdir())}


def check_outputs(study: StudyResult, kind: str) -> list[dict]:
    for name in ("csv", "json", "png", "text"):
        assert study.files[name].exists(), name
    assert study.files["png"].read_bytes()[:8] == PNG_MAGIC
    summary = json.loads(study.files["json"].read_text())
    assert summary["kind"] == kind and summary["table"] == json.loads(json.dumps(study.rows))
    with open(study.files["csv"], newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(study.rows)
    assert study.files["text"].read_text().strip() == study.text.strip()
    return rows


# -- option parsing ---------------------------------------------------------------------
def test_parse_study_options_reads_yaml_values():
    opts = parse_study_options(["n_runs=7", "n_values=2..40:2", "keep_runs=true", "reference_n=null",
                                "n_values=[2, 5]", "tolerance=0.05"])
    assert opts == {"n_runs": 7, "n_values": [2, 5], "keep_runs": True, "reference_n": None, "tolerance": 0.05}
    with pytest.raises(ConfigError, match="expected key=value"):
        parse_study_options(["n_runs"])
    with pytest.raises(ConfigError, match="expected key=value"):
        parse_study_options(["=3"])


def test_element_counts_and_option_validation():
    assert parse_int_list("2..6") == [2, 3, 4, 5, 6]
    assert parse_int_list("2..10:4") == [2, 6, 10]
    assert parse_int_list("2,4, 8") == [2, 4, 8]
    assert validate_study_options("element_sweep", {"n_values": "10,2,2"}).n_values == [2, 10]
    with pytest.raises(ConfigError, match="element counts"):
        validate_study_options("element_sweep", {"n_values": "two..ten"})
    with pytest.raises(ConfigError, match="did you mean 'n_runs'"):
        validate_study_options("monte_carlo", {"n_run": 5})
    with pytest.raises(ConfigError, match="did you mean 'monte_carlo'"):
        validate_study_options("monte_carl", {})
    with pytest.raises(ConfigError, match="n_runs"):
        validate_study_options("repeatability", {"n_runs": 1})


def test_settle_index():
    assert settle_index([1.0, 2.0, 1.5, 1.01, 1.0, 1.005], 0.02) == 3
    assert settle_index([1.0, 1.001, 1.002], 0.02) == 0
    assert settle_index([1.0, 2.0, 4.0, 8.0], 0.02) is None  # only the last point: not settled
    assert settle_index([1.0, 1.5, 1.0, 1.5], 0.02) is None


# -- Monte Carlo ---------------------------------------------------------------------------
def test_monte_carlo_statistics_on_known_numbers():
    from mbus_framework.studies.monte_carlo import monte_carlo_statistics

    est = np.array([9.0, 10.5, 11.0, 12.0, 10.0])
    se = np.array([0.4, 0.5, 1.0, 0.5, 0.1])
    ci = np.column_stack([est - 2 * se, est + 2 * se])  # covers 10 in runs 2, 3 and 5 only
    s = monte_carlo_statistics(est, 10.0, se, ci, crb=0.5)
    assert s["bias"] == pytest.approx(0.5) and s["bias_percent"] == pytest.approx(5.0)
    assert s["rmse"] == pytest.approx(np.sqrt((1 + 0.25 + 1 + 4 + 0) / 5))
    assert s["rmse_over_crb"] == pytest.approx(s["rmse"] / 0.5)
    assert s["mean_se"] == pytest.approx(0.5)
    assert s["covered"] == 3 and s["coverage"] == pytest.approx(0.6)
    assert s["within_3se"] == 4  # run 4: |2| > 1.5
    # Clopper-Pearson 95 % interval of 3/5
    assert (s["coverage_low"], s["coverage_high"]) == pytest.approx((0.1466, 0.9473), abs=1e-4)


def test_monte_carlo_statistics_match_the_runs(tmp_path):
    progress = RecordingProgress()
    study = run_study("monte_carlo", SMALL, [], tmp_path / "mc", progress=progress, n_runs=4, first_seed=20)
    csv_rows = check_outputs(study, "monte_carlo")
    assert progress.events[0] == ("start", 4) and progress.events[-1] == ("stop", None)
    assert sum(e[0] == "advance" for e in progress.events) == 4

    results = run_results(study)
    assert sorted(results) == [f"seed-{s:05d}" for s in range(20, 24)]
    configs = run_configs(study)
    assert [c["backend"]["options"]["seed"] for c in configs.values()] == [20, 21, 22, 23]
    truth = {"k_sigma": 1.2e8, "b_sigma": 6.0, "k_tau": 2.0e7, "b_tau": 5.0}
    rows = {r["quantity"]: r for r in study.rows}
    assert set(rows) == set(truth) | {"E_sigma", "eta_sigma", "E_tau", "eta_tau"}

    for name, true in truth.items():
        est = np.array([r["parameters"][name] for r in results.values()])
        se = np.array([r["uncertainty"]["standard_errors"][name] for r in results.values()])
        ci = np.array([r["uncertainty"]["ci95"][name] for r in results.values()])
        row = rows[name]
        assert row["truth"] == pytest.approx(true)
        assert row["bias"] == pytest.approx(est.mean() - true, rel=1e-9, abs=1e-12 * true)
        assert row["rmse"] == pytest.approx(np.sqrt(np.mean((est - true) ** 2)), rel=1e-9)
        assert row["std"] == pytest.approx(est.std(ddof=1), rel=1e-9)
        assert row["mean_se"] == pytest.approx(se.mean(), rel=1e-9)
        assert row["covered"] == int(np.sum((ci[:, 0] <= true) & (true <= ci[:, 1])))
        assert row["within_3se"] == int(np.sum(np.abs(est - true) <= 3 * se))
        assert row["rmse_over_crb"] == pytest.approx(row["rmse"] / row["crb"], rel=1e-9)
        assert row["coverage_low"] <= row["coverage"] <= row["coverage_high"]

    # Cramer-Rao bound recomputed from scratch: central differences of the exact simulator,
    # sigma = 10 % of the RMS of the noise-free output.
    from mbus_framework.interfaces.sample import Sample
    from mbus_framework.engine.simulation import simulate
    from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
    from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

    model = KelvinVoigtChain(Sample(0.05, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=4))
    wave = Prbs(PrbsOptions(order=9, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=1500)).waveform()
    dt = wave.t[1] - wave.t[0]
    theta = np.array([truth[n] for n in model.parameter_names])
    y0 = simulate(model, theta, wave.u, dt)
    sigma = 0.10 * np.sqrt(np.mean(y0**2))
    J = np.empty((y0.size, 4))
    for i in range(4):
        h = 1e-5 * theta[i]
        up, dn = theta.copy(), theta.copy()
        up[i] += h
        dn[i] -= h
        J[:, i] = (simulate(model, up, wave.u, dt) - simulate(model, dn, wave.u, dt)) / (2 * h)
    crb = sigma * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    for name, bound in zip(model.parameter_names, crb):
        assert rows[name]["crb"] == pytest.approx(bound, rel=1e-3)
    # E_sigma = (L/n)/(pi D^2/4) k_sigma is linear, so its bound scales the same way.
    g = (0.05 / 4) / (np.pi * 0.0254**2 / 4)
    assert rows["E_sigma"]["crb"] == pytest.approx(g * crb[0], rel=1e-3)
    assert rows["eta_tau"]["crb"] == pytest.approx(crb[3] / (np.pi * 0.0254), rel=1e-3)

    props = [r["properties"]["E_tau"] for r in results.values()]
    true_e_tau = 2.0e7 / (np.pi * 0.0254)
    assert rows["E_tau"]["rmse"] == pytest.approx(np.sqrt(np.mean((np.array(props) - true_e_tau) ** 2)), rel=1e-9)
    assert float(csv_rows[0]["rmse"]) == pytest.approx(study.rows[0]["rmse"], rel=1e-12)
    assert "RMS/CRB" in study.text and "k_sigma" in study.text
    # Runs keep only their result and config, not the waveforms (keep_runs=false).
    assert not any((study.out_dir / "runs").glob("*/measurement.csv"))


def test_monte_carlo_needs_a_seeded_rig(tmp_path):
    data = yaml.safe_load(SMALL.read_text())
    data["backend"] = {"name": "file", "options": {"path": str(tmp_path / "none.csv")}}
    cfg = tmp_path / "file.yaml"
    cfg.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="seed"):
        run_study("monte_carlo", cfg, [], tmp_path / "out", n_runs=2)


# -- element sweep -------------------------------------------------------------------------
def test_element_sweep_fits_one_fine_medium(tmp_path):
    study = run_study("element_sweep", SMALL, [], tmp_path / "sweep", n_values=[3, 4], reference_n=6,
                      tolerance=0.5, keep_runs=True)
    check_outputs(study, "element_sweep")
    results, configs = run_results(study), run_configs(study)
    # a cold fit per n, and n = 3 again from the n = 4 estimate (warm start)
    assert sorted(results) == ["n-003", "n-003-warm", "n-004"]
    geometry = (0.05 / 4) / (np.pi * 0.0254**2 / 4)
    true_props = {"E_sigma": geometry * 1.2e8, "eta_sigma": geometry * 6.0,
                  "E_tau": 2.0e7 / (np.pi * 0.0254), "eta_tau": 5.0 / (np.pi * 0.0254)}
    for label, cfg in configs.items():
        backend = cfg["backend"]["options"]
        assert backend["medium"]["options"]["n_elements"] == 6
        assert backend["truth"] == pytest.approx(true_props, rel=1e-12)
        assert cfg["model"]["options"]["n_elements"] == int(label[2:5])
        assert results[label]["truth_properties"] == pytest.approx(true_props, rel=1e-9)
        # same record for every n: the true medium, noise and seed do not change
        assert (study.out_dir / "runs" / label / "measurement.csv").exists()
    # initial values are passed as properties (parameters depend on n)
    assert configs["n-003"]["model"]["initial"]["E_sigma"] == pytest.approx(geometry * 1.5e8, rel=1e-12)
    assert configs["n-003-warm"]["model"]["initial"] == pytest.approx(results["n-004"]["properties"], rel=1e-12)
    rec3 = np.loadtxt(study.out_dir / "runs/n-003/measurement.csv", delimiter=",", skiprows=1)
    rec4 = np.loadtxt(study.out_dir / "runs/n-004/measurement.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(rec3, rec4)

    # the row of n = 3 is the lower-cost of its two fits
    cost = {k: r["solver"]["cost"] for k, r in results.items()}
    assert study.rows[0]["run"] == min(["n-003", "n-003-warm"], key=cost.get)
    assert study.rows[1]["run"] == "n-004"
    best = {row["n_elements"]: results[row["run"]] for row in study.rows}
    for row in study.rows:
        res = best[row["n_elements"]]
        for p in true_props:
            assert row[p] == pytest.approx(res["properties"][p], rel=1e-12)
            assert row[f"{p}_error"] == pytest.approx(res["properties"][p] / true_props[p] - 1, rel=1e-9)
    for p in true_props:
        v3, v4 = best[3]["properties"][p], best[4]["properties"][p]
        assert study.rows[1][f"{p}_change"] == pytest.approx(v4 / v3 - 1, rel=1e-9)
        expected = 3 if abs(v4 - v3) <= 0.5 * abs(v3) else None
        assert study.summary["settled_at"][p] == expected
    assert "settle" in study.text


def test_element_sweep_needs_an_element_count(tmp_path):
    with pytest.raises(ConfigError, match="n_values"):
        run_study("element_sweep", SMALL, [], tmp_path / "x", n_values=[4])


# -- repeatability ---------------------------------------------------------------------------
def test_repeatability_table_matches_the_runs(tmp_path):
    study = run_study("repeatability", SMALL, [], tmp_path / "rep", n_runs=3)
    check_outputs(study, "repeatability")
    results, configs = run_results(study), run_configs(study)
    assert sorted(results) == ["prbs-01", "prbs-02", "prbs-03"]
    step = 511 // 3
    assert [c["excitation"]["options"]["shift"] for c in configs.values()] == [0, step, 2 * step]
    assert [c["backend"]["options"]["seed"] for c in configs.values()] == [11, 12, 13]
    # same bandwidth: only the start of the sequence changes
    for c in configs.values():
        assert c["excitation"]["options"]["bit_width"] == 2.5e-6
    by_run = {r["run"]: r for r in study.rows}
    assert list(by_run) == ["PRBS-1", "PRBS-2", "PRBS-3", "Mean", "Std/Mean"]
    for p in ("E_sigma", "eta_sigma", "E_tau", "eta_tau", "k_sigma", "b_tau"):
        v = np.array([r["properties"][p] if p in r["properties"] else r["parameters"][p] for r in results.values()])
        assert by_run["Mean"][p] == pytest.approx(v.mean(), rel=1e-12)
        assert by_run["Std/Mean"][p] == pytest.approx(v.std(ddof=1) / abs(v.mean()), rel=1e-9)
        assert [by_run[f"PRBS-{i}"][p] for i in (1, 2, 3)] == pytest.approx(list(v), rel=1e-12)
    assert "Std/Mean" in study.text


def test_repeatability_by_shift_only_keeps_the_noise_seed(tmp_path):
    study = run_study("repeatability", SMALL, [], tmp_path / "rep", n_runs=2, vary="shift", shift_step=100)
    configs = run_configs(study)
    assert [c["excitation"]["options"]["shift"] for c in configs.values()] == [0, 100]
    assert [c["backend"]["options"]["seed"] for c in configs.values()] == [11, 11]
    assert study.summary["vary"] == "shift"
