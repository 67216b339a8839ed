"""Model comparison: statistics, ranking, rendering and the config-driven command."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from mbus_framework.studies.compare import (
    Candidate,
    ComparisonTable,
    ComparisonData,
    compare_models,
    information_criteria,
    ljung_box,
    ModelRow,
    render_table,
    run_comparison,
)
from mbus_framework.interfaces.model import StateSpace
from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import simulate
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.models.maxwell import MaxwellChain, MaxwellOptions
from mbus_plugins.models.sls import SlsChain, SlsOptions
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions
from test_report import assert_folder_report

SAMPLE = Sample(length=0.05, diameter=0.0254, density=1000.0)
N_EL = 6
TRUTH = {"kelvin_voigt": [3e8, 15.0, 5e7, 12.0], "maxwell": [3e8, 900.0, 5e7, 500.0],
         "sls": [2e8, 1e8, 300.0, 4e7, 1e7, 100.0]}


def models():
    return {
        "kelvin_voigt": KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=N_EL)),
        "maxwell": MaxwellChain(SAMPLE, MaxwellOptions(n_elements=N_EL)),
        "sls": SlsChain(SAMPLE, SlsOptions(n_elements=N_EL)),
    }


def record(generator: str, seed=0):
    w = Prbs(PrbsOptions(order=9, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=2000)).waveform()
    y0 = simulate(models()[generator], TRUTH[generator], w.u, w.dt)
    y = y0 + np.random.default_rng(seed).normal(0, 0.05 * np.sqrt(np.mean(y0**2)), y0.shape)
    return ComparisonData(w.t, w.u, y)


def solver(n_starts=4):
    return ScipyLM(ScipyLMOptions.model_validate({"strategy": {"n_starts": n_starts}}))


def test_ljung_box_tells_white_from_coloured():
    rng = np.random.default_rng(0)
    white = rng.normal(size=3000)
    q, p, h = ljung_box(white)
    assert h == 20 and p > 0.01
    coloured = np.convolve(white, np.ones(5) / 5, mode="same")
    q2, p2, _ = ljung_box(coloured)
    assert q2 > 100 * q and p2 < 1e-10
    # known value: r_1 = 0.5 only, N = 4 -> Q = N (N+2) r^2 / (N-1)
    e = np.array([1.0, 1.0, -1.0, -1.0])  # r_1 = 0, r_2 = -1 ... computed directly below
    r = [float(e[:-k] @ e[k:]) / float(e @ e) for k in (1, 2)]
    assert ljung_box(e, lags=2)[0] == pytest.approx(4 * 6 * (r[0] ** 2 / 3 + r[1] ** 2 / 2))


def test_information_criteria():
    aic, bic = information_criteria(rss=2.0, n=100, p=4)
    assert aic == pytest.approx(100 * np.log(0.02) + 8)
    assert bic == pytest.approx(100 * np.log(0.02) + 4 * np.log(100))
    assert np.isnan(information_criteria(0.0, 10, 1)[0])


def test_comparison_picks_the_generating_model():
    table = compare_models(record("sls"), models(), solver())
    assert table.best == "sls"
    best = table.row("sls")
    assert best.best and best.delta == 0 and best.white
    assert all(r.delta > 10 for r in table.rows if r is not best)  # BIC difference > 10: decisive
    assert not table.row("kelvin_voigt").white and not table.row("maxwell").white
    # every parameter of the generating model within 3 standard errors of the truth
    truth = dict(zip(best.parameters, TRUTH["sls"]))
    for name, value in best.parameters.items():
        assert abs(value - truth[name]) < 3 * best.standard_errors[name], name
    text = render_table(table)
    lines = text.splitlines()
    assert any(line.startswith("* sls") for line in lines)
    assert all(any(name in line for line in lines) for name in ("kelvin_voigt", "maxwell", "AIC", "BIC", "LB p"))
    assert "k1_sigma" in text and "+-" in text
    doc = json.loads(json.dumps(table.as_dict()))
    assert doc["best"] == "sls" and len(doc["models"]) == 3


def test_a_failing_model_is_reported_not_fatal():
    class Exploding(KelvinVoigtChain):
        def state_space(self, theta) -> StateSpace:
            raise FloatingPointError("boom")

    cands = [Candidate("good", models()["kelvin_voigt"]),
             Candidate("bad", Exploding(SAMPLE, KelvinVoigtOptions(n_elements=N_EL)))]
    table = compare_models(record("kelvin_voigt"), cands, solver(1))
    assert table.best == "good"
    assert "boom" in table.row("bad").error
    assert "failed: FloatingPointError: boom" in render_table(table)
    with pytest.raises(ValueError):
        compare_models(record("kelvin_voigt"), [("a", models()["sls"]), ("a", models()["sls"])], solver(1))


def _config(tmp_path, model="sls", truth=None):
    cfg = {
        "title": "comparison test",
        "sample": {"length": 0.05, "diameter": 0.0254, "density": 1000.0},
        "model": {"name": model, "options": {"n_elements": N_EL}},
        "excitation": {"name": "prbs", "options": {"order": 9, "bit_width": 2.5e-6, "sample_rate": 6.25e6,
                                                   "n_samples": 2000}},
        "backend": {"name": "simulated", "options": {"truth": truth or dict(zip(
            models()[model].parameter_names, TRUTH[model])), "noise": {"relative_std": 0.05}, "seed": 3}},
        "solver": {"name": "scipy_lm", "options": {"strategy": {"n_starts": 4}}},
        "output": {"directory": str(tmp_path / "runs"), "plots": True},
    }
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_run_comparison_from_a_config(tmp_path):
    path = _config(tmp_path)
    out = tmp_path / "out"
    table, text = run_comparison(path, ["kelvin_voigt", "sls", "maxwell"], [], out_dir=out)
    assert table.best == "sls"
    assert (out / "measurement.csv").exists()  # the record is saved before any fit
    assert (out / "comparison.txt").read_text().strip() == text.strip()
    doc = json.loads((out / "comparison.json").read_text())
    assert doc["best"] == "sls" and [m["name"] for m in doc["models"]] == ["kelvin_voigt", "sls", "maxwell"]
    assert (out / "comparison_bode.png").read_bytes()[:4] == b"\x89PNG"
    assert_folder_report(out, 1, text.strip().splitlines()[0].strip())
    # options of the configured model carry over (n_elements) to the others
    assert table.row("kelvin_voigt").model.n == N_EL


def test_run_comparison_errors(tmp_path):
    from mbus_framework.errors import ConfigError, PluginError

    path = _config(tmp_path)
    with pytest.raises(PluginError, match="did you mean 'maxwell'"):
        run_comparison(path, ["maxwel"], [], out_dir=tmp_path / "x")
    with pytest.raises(ConfigError):
        run_comparison(path, [" "], [], out_dir=tmp_path / "y")


@pytest.mark.slow
@pytest.mark.parametrize("generator", ["kelvin_voigt", "maxwell", "sls"])
def test_comparison_picks_each_generating_model_default_solver(generator):
    table = compare_models(record(generator, seed=5), models(), ScipyLM(ScipyLMOptions()))
    assert table.best == generator
    assert table.row(generator).white


def test_mbus_run_compare_models_flag(tmp_path, capsys):
    from mbus_framework.cli import main

    path = _config(tmp_path)
    out = tmp_path / "cli"
    assert main([str(path), "--compare-models", "kelvin_voigt,sls", "-o", str(out), "--no-plots"]) == 0
    printed = capsys.readouterr().out
    assert any(line.startswith("* sls") for line in printed.splitlines())
    assert (out / "comparison.json").exists()


def test_render_table_shows_properties_units_ses_and_warnings():
    row = ModelRow("sls", 2, 100, cost=1.0, aic=1.0, bic=1.0, delta=0.0, success=True, best=True,
                   parameters={"k_sigma": 2.0e8, "b1_sigma": 3.0}, standard_errors={"k_sigma": 1e6, "b1_sigma": 1.98},
                   parameter_units={"k_sigma": "N/m", "b1_sigma": "N s/m"},
                   properties={"E_sigma": 2.4e10}, property_units={"E_sigma": "Pa"},
                   property_standard_errors={"E_sigma": 1.2e8},
                   warnings=["practically unidentifiable, standard error above 20 % of the estimate: b1_sigma (66 %)"])
    text = render_table(ComparisonTable([row], "bic", 100, "sls"))
    assert "k_sigma" in text and " N/m " in text and "(0.5 %)" in text and "(66 %)" in text
    assert any(line.split()[:5] == ["E_sigma", "2.4e+10", "+-", "1.2e+08", "Pa"] for line in text.splitlines())
    assert "    warning: practically unidentifiable, standard error above 20 % of the estimate: b1_sigma (66 %)" in text


@pytest.mark.slow
def test_comparison_reports_properties_units_and_the_single_run_warnings(tmp_path):
    """Each model's properties carry units and standard errors, and its warnings are those a
    single run of it gives: with a 0.01 % limit on the relative SE every parameter is flagged,
    in the comparison as in ``mbus-run`` of the same config."""
    from mbus_framework.pipeline.run import execute

    path = _config(tmp_path)
    strict = ["identifiability.max_relative_se=1e-4", "solver.options.strategy.n_starts=1"]
    table, text = run_comparison(path, ["sls", "kelvin_voigt"], strict, out_dir=tmp_path / "cmp")
    sls = table.row("sls")
    assert sls.property_units["E_sigma"] == "Pa" and sls.property_units["eta1_sigma"] == "Pa s"
    assert set(sls.property_standard_errors) == set(sls.properties)
    assert all(np.isfinite(v) and v > 0 for v in sls.property_standard_errors.values())
    flagged = [w for w in sls.warnings if w.startswith("practically unidentifiable")]
    assert len(flagged) == 1 and all(n in flagged[0] for n in sls.standard_errors)
    assert f"    warning: {flagged[0]}" in text
    e = sls.properties["E_sigma"]
    assert any(line.split()[:2] == ["E_sigma", f"{e:.6g}"] and " Pa " in line for line in text.splitlines())
    single = execute(path, strict, tmp_path / "single", plots=False)
    single_flagged = [w for w in single.result["warnings"] if w.startswith("practically unidentifiable")]
    assert len(single_flagged) == 1
    assert all(n in single_flagged[0] for n in sls.standard_errors)
    doc = json.loads((tmp_path / "cmp" / "comparison.json").read_text())
    assert doc["models"][0]["warnings"] == sls.warnings and doc["models"][0]["property_units"]["E_sigma"] == "Pa"
    # the flag follows the limit: at the default 20 % the well-identified kelvin_voigt stiffnesses pass
    kv = table.row("kelvin_voigt")
    assert all(100 * kv.relative_standard_errors()[n] > 0.01 for n in kv.standard_errors)
