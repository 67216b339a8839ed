"""Joint estimation over several records (mbus_framework.joint)."""
from __future__ import annotations

import numpy as np
import pytest

import mbus_framework as mbus
from mbus_framework.errors import ConfigError
from mbus_framework.estimation.nuisance import delayed_prediction
from mbus_framework.interfaces.sample import Sample
from mbus_framework.joint.spec import JointSpec
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

POTATO = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}
OTHER = {"E_sigma": 2.0e10, "eta_sigma": 9.0e3, "E_tau": 5.0e9, "eta_tau": 6.5e3}  # a different potato
DIAMETER, DENSITY, N_ELEMENTS, DT = 0.0254, 1080.0, 4, 4e-8
PROPS = list(POTATO)


def geometry(length: float) -> dict[str, float]:
    return {"length": length, "diameter": DIAMETER, "density": DENSITY}


def record(length: float, truth=POTATO, gain: float = 1.0, delay_samples: float = 0.0, noise: float = 0.03,
           n: int = 1000, seed: int = 0) -> mbus.Record:
    """A simulated record: a random-telegraph ZOH input (10-sample bits), g * y(t - tau) + white noise."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-1.0, 1.0], size=n // 10 + 1), 10)[:n]
    model = KelvinVoigtChain(Sample(length, DIAMETER, DENSITY), KelvinVoigtOptions(n_elements=N_ELEMENTS))
    y = delayed_prediction(model, model.from_properties(truth), u, DT, gain, delay_samples * DT)
    y = y + noise * np.sqrt(np.mean(y**2)) * rng.standard_normal(n)
    return mbus.Record(np.arange(n) * DT, u, y)


FIT = dict(model="kelvin_voigt", model_options={"n_elements": N_ELEMENTS}, plots=False)


def test_one_record_joint_equals_single():
    rec = record(0.03, seed=1)
    single = mbus.fit(*rec, sample=geometry(0.03), **FIT)
    joint = mbus.fit([rec], sample=geometry(0.03), **FIT)
    for name in PROPS:
        assert joint.properties[name].value == pytest.approx(single.properties[name].value, rel=1e-6)
        assert joint.properties[name].std_error == pytest.approx(single.properties[name].std_error, rel=1e-3)
    assert joint.agreement["df"] == 0 and joint.agreement["p_value"] == 1.0
    assert joint.records[0]["fit"]["chi2"] == pytest.approx(joint.records[0]["fit"]["chi2_own_fit"], rel=1e-6)


def test_joint_jacobian_matches_finite_differences():
    from mbus_framework.estimation.nuisance import NuisanceSettings
    from mbus_framework.estimation.problem import FitProblem
    from mbus_framework.joint.problem import JointProblem

    spec = JointSpec.declare(PROPS, ["E_sigma", "eta_sigma", "E_tau"], ["input_gain", "delay", "eta_tau"])
    problems = []
    for length, gain, delay, seed in ((0.02, 1.5, 3.3, 2), (0.03, 0.7, 7.6, 3)):
        t, u, y = record(length, gain=gain, delay_samples=delay, seed=seed, n=600)
        model = KelvinVoigtChain(Sample(length, DIAMETER, DENSITY), KelvinVoigtOptions(n_elements=N_ELEMENTS))
        problems.append(FitProblem(model, t, u, y, nuisance=NuisanceSettings(estimate_gain=True, estimate_delay=True)))
    jp = JointProblem(problems, spec, [0.02, 0.05], ["a", "b"])
    assert [s.name for s in jp.slots] == ["E_sigma", "eta_sigma", "E_tau", "eta_tau", "input_gain", "delay",
                                          "eta_tau", "input_gain", "delay"]
    phi = 1.01 * np.array([*(POTATO[n] for n in PROPS[:3]), 5.0e3, 1.4, 3.1 * DT, 5.3e3, 0.75, 7.2 * DT])
    w, J = jp.residuals_and_jacobian(phi)
    assert np.allclose(w, np.concatenate(jp.weighted_residuals(phi)))
    for i in range(len(phi)):
        h = 1e-6 * phi[i]
        up, dn = phi.copy(), phi.copy()
        up[i] += h
        dn[i] -= h
        fd = -(np.concatenate(jp.weighted_residuals(up)) - np.concatenate(jp.weighted_residuals(dn))) / (2 * h)
        assert np.linalg.norm(J[:, i] - fd) <= 1e-5 * np.linalg.norm(fd), jp.names[i]
    # block structure: record 1's rows do not depend on record 2's own parameters
    n1 = jp.problems[0].y.size
    assert np.all(J[:n1, 6:] == 0) and np.all(J[n1:, 3:6] == 0)


def test_two_thicknesses_recover_shared_properties_better_than_either_record():
    recs = [record(0.02, gain=1.8, delay_samples=5.0, seed=4), record(0.03, gain=0.6, delay_samples=12.0, seed=5)]
    samples = [geometry(0.02), geometry(0.03)]
    joint = mbus.fit(recs, sample=samples, per_record=["input_gain", "delay"], labels=["2 cm", "3 cm"], **FIT)
    # each record's own fit (the single-record pipeline, same nuisance settings) is kept in the result
    single_se = [rec["own_fit"]["property_standard_errors"] for rec in joint.records]
    for name in PROPS:
        e = joint.properties[name]
        assert abs(e.value - POTATO[name]) < 4 * e.std_error, (name, e.value, e.std_error)
        assert e.std_error < min(se[name] for se in single_se), name
    gains = {rec["label"]: rec["nuisance"]["input_gain"] for rec in joint.records}
    assert gains["2 cm"] == pytest.approx(1.8, rel=0.02) and gains["3 cm"] == pytest.approx(0.6, rel=0.02)
    assert joint.agreement["p_value"] > 0.01 and not joint.warnings
    assert all(rec["verdict"]["accepted"] for rec in joint.records)
    table = joint.to_dataframe()
    assert set(table["record"]) == {"shared", "2 cm", "3 cm"}
    assert len(table) == 4 + 2 * 2


def test_record_of_another_material_is_flagged():
    recs = [record(0.02, gain=1.3, seed=6), record(0.03, truth=OTHER, gain=0.8, seed=7)]
    joint = mbus.fit(recs, sample=[geometry(0.02), geometry(0.03)], per_record=["input_gain"], **FIT)
    assert joint.agreement["p_value"] < 0.01 and not joint.agreement["agree"]
    assert joint.agreement["df"] == 4
    assert "do not agree" in joint.warnings[0]


@pytest.mark.parametrize("shared, per_record, message", [
    (["E_sigma", "E_modulus"], [], "E_modulus: not a property of this model"),
    (["E_sigma", "eta_sigma"], ["eta_sigma"], "eta_sigma is declared both shared and per_record"),
    (["E_sigma", "input_gain"], [], "input_gain is a nuisance parameter"),
    ([], list(POTATO), "no shared property"),
])
def test_declaration_errors_are_one_line(shared, per_record, message):
    with pytest.raises(ConfigError, match=message) as info:
        JointSpec.declare(PROPS, shared, per_record, where="x.yaml: joint")
    assert "\n" not in str(info.value) and str(info.value).startswith("x.yaml: joint")


def test_declaration_defaults_share_every_other_property():
    spec = JointSpec.declare(PROPS, None, ["eta_tau", "delay"])
    assert spec.shared == ("E_sigma", "eta_sigma", "E_tau") and spec.per_record == ("eta_tau",)
    assert spec.nuisance == ("delay",)


def _config(tmp_path, records, joint_extra=""):
    text = f"""
title: joint check
sample: {{length: 0.03, diameter: 0.0254, density: 1080.0}}
model: {{name: kelvin_voigt, options: {{n_elements: 4}}}}
excitation: {{name: prbs, options: {{order: 7, bit_width: 0.4e-6, sample_rate: 25.0e6, n_samples: 1000}}}}
backend: {{name: simulated, options: {{truth: {POTATO}, noise: {{relative_std: 0.03}}}}}}
joint:
  {joint_extra}
  records:
{records}
"""
    path = tmp_path / "joint.yaml"
    path.write_text(text)
    return path


def test_cli_config_errors_are_one_line(tmp_path, capsys):
    from mbus_framework.cli import main

    cases = [
        ("    - {label: a}\n    - {label: b, model: {options: {n_elements: 6}}}", "", "differs from records[0]"),
        ("    - {label: a}\n    - {label: b}", "shared: [E_sigma, Poisson]", "Poisson: not a property"),
        ("    - {label: a}\n    - {label: b}", "shared: [E_sigma]\n  per_record: [E_sigma]", "both shared and per_record"),
        ("    - {label: a}\n    - {label: a}", "", "'a' is used twice"),
        ("    - {label: a, sample: {lenght: 0.02}}", "", "joint.records[0]: sample.lenght: unknown key"),
    ]
    for records, extra, message in cases:
        path = _config(tmp_path, records, extra)
        assert main([str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and "\n" not in err and str(path) in err, err
        assert not (tmp_path / "run").exists()  # nothing acquired before the declaration is checked


def test_cli_runs_a_joint_config(tmp_path, capsys):
    import json

    from mbus_framework.cli import main

    records = ("    - {label: thin, sample: {length: 0.02}, backend: {options: {input_gain: 1.5, seed: 1}}}\n"
               "    - {label: thick, backend: {options: {input_gain: 0.8, seed: 2}}}")
    path = _config(tmp_path, records, "per_record: [input_gain]")
    assert main([str(path), "--out", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out
    assert "E_sigma" in out and "input_gain = 1.5" in out and "agreement" in out
    doc = json.loads((tmp_path / "run" / "result.json").read_text())
    assert set(doc["properties"]) == set(POTATO) and doc["agreement"]["df"] == 4
    assert [r["label"] for r in doc["records"]] == ["thin", "thick"]
    assert doc["records"][0]["nuisance"]["input_gain"] == pytest.approx(1.5, rel=0.02)
    assert doc["records"][0]["sample"]["length"] == 0.02 and "verdict" in doc["records"][1]
    assert (tmp_path / "run" / "records" / "2" / "measurement.csv").is_file()


def test_api_input_errors_are_one_line():
    a, b = record(0.02, n=300, seed=8), record(0.03, n=300, seed=9)
    with pytest.raises(ConfigError, match="3 geometries for 2 records"):
        mbus.fit([a, b], sample=[geometry(0.02)] * 3, **FIT)
    with pytest.raises(ConfigError, match="Poisson: not a property"):
        mbus.fit([a, b], sample=geometry(0.02), shared=["Poisson"], **FIT)
    with pytest.raises(ConfigError, match="fixed and out_dir are for one record"):
        mbus.fit([a, b], sample=geometry(0.02), fixed={"k_tau": 1.0}, **FIT)
    with pytest.raises(ConfigError, match="shared and per_record need a list of records"):
        mbus.fit(*a, sample=geometry(0.02), shared=["E_sigma"], **FIT)
    with pytest.raises(TypeError, match="give t, u, y arrays"):
        mbus.fit(a.t, sample=geometry(0.02), **FIT)
