"""Layered samples: one layer equals the plain chain exactly; shared and fixed coefficients."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import simulate
from mbus_framework.estimation.problem import FitProblem
from mbus_framework.estimation.uncertainty import from_jacobian
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.generalized_maxwell import GeneralizedMaxwellChain, GeneralizedMaxwellOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.models.layered import LayeredChain, LayeredOptions
from mbus_plugins.models.maxwell import MaxwellChain, MaxwellOptions
from mbus_plugins.models.sls import SlsChain, SlsOptions
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions

SAMPLE = Sample(length=0.05, diameter=0.0254, density=1000.0)

PLAIN = {
    "kelvin_voigt": (lambda n: KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n)), {}),
    "maxwell": (lambda n: MaxwellChain(SAMPLE, MaxwellOptions(n_elements=n)), {}),
    "sls": (lambda n: SlsChain(SAMPLE, SlsOptions(n_elements=n)), {}),
    "generalized_maxwell": (
        lambda n: GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=n, n_arms=2,
                                                                            shear_link="generalized_maxwell")),
        {"n_arms": 2}),
}


@settings(max_examples=20)
@given(law=st.sampled_from(sorted(PLAIN)), n=st.integers(1, 15), data=st.data())
def test_one_layer_equals_plain_chain_exactly(law, n, data):
    size = len(PLAIN[law][0](n).parameters)
    _check_one_layer(law, n, data.draw(st.lists(st.floats(-2, 2), min_size=size, max_size=size)))


def test_one_layer_equals_plain_chain_for_a_stiff_sls_chain():
    """The example a fresh-clone run found: eigenvectors conditioned at 5.6e5."""
    _check_one_layer("sls", 12, [-2.0, 0.0, -1.0, 2.0, 0.0, 0.0])


def _check_one_layer(law: str, n: int, logs) -> None:
    make, extra = PLAIN[law]
    plain = make(n)
    layered = LayeredChain(SAMPLE, LayeredOptions(link=law, layers=[{"n_elements": n}], **extra))
    theta = np.array([p.typical for p in plain.parameters]) * np.exp(logs)
    for a, b in zip(layered.state_space(theta), plain.state_space(theta)):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)  # to round-off: the plain chain's assembly is compiled
    np.testing.assert_array_equal(layered.masses(), plain.masses())
    assert layered.parameter_names == [f"{p}_layer1" for p in plain.parameter_names]
    assert [p.typical for p in layered.parameters] == [p.typical for p in plain.parameters]
    assert list(layered.to_properties(theta).values()) == list(plain.to_properties(theta).values())
    u = np.sign(np.sin(np.arange(400) / 7.0))
    y_layered, y_plain = simulate(layered, theta, u, 1.6e-7), simulate(plain, theta, u, 1.6e-7)
    # the matrices agree to an ulp; the modal simulation amplifies that by the condition number
    # of A's eigenvectors (5.6e5 for a stiff SLS chain: outputs 8e-9 of the peak apart)
    _, vectors = np.linalg.eig(np.asarray(plain.state_space(theta)[0], float))
    tol = 1e-9 + 1e3 * np.linalg.cond(vectors) * np.finfo(float).eps
    np.testing.assert_allclose(y_layered, y_plain, rtol=tol, atol=tol * np.max(np.abs(y_plain)))


def test_same_material_in_two_layers_is_the_uniform_chain():
    """Shared coefficients with equal element lengths: the stack is the uniform chain."""
    two = LayeredChain(SAMPLE, LayeredOptions(shared=["k_sigma", "b_sigma", "k_tau", "b_tau"], layers=[
        {"name": "a", "length": 0.02, "n_elements": 2}, {"name": "b", "n_elements": 3}]))
    one = KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=5))
    assert two.parameter_names == ["k_sigma", "b_sigma", "k_tau", "b_tau"]
    theta = np.array([3e8, 15.0, 5e7, 12.0])
    for a, b in zip(two.state_space(theta), one.state_space(theta)):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=0)
    np.testing.assert_allclose(list(two.to_properties(theta).values()), list(one.to_properties(theta).values()),
                               rtol=1e-13)


def test_shared_normal_coefficient_keeps_the_modulus():
    """Layers with different element lengths sharing k_sigma share E_sigma (eq. 3.32)."""
    m = LayeredChain(SAMPLE, LayeredOptions(shared=["k_sigma"], layers=[
        {"name": "thin", "length": 0.01, "n_elements": 2}, {"name": "thick", "n_elements": 2}]))
    theta = np.array([p.typical for p in m.parameters])
    vals = m.layer_values(theta)
    # element lengths 5 mm and 20 mm: k = E A / l, so k_thick = k_thin * 5/20
    assert vals[1][0] == pytest.approx(vals[0][0] * 0.25, rel=1e-14)
    E = m.to_properties(theta)["E_sigma"]
    for layer, v in zip(m.layers, vals):
        assert layer.coefficient_to_property("sigma", v[0]) == pytest.approx(E, rel=1e-14)


def test_fixed_plate_properties_and_boundary_masses():
    plate = {"name": "plate", "length": 0.006, "density": 1180.0, "n_elements": 2,
             "fixed": {"E_sigma": 5.6e9, "eta_sigma": 40.0, "k_tau": 1e7, "eta_tau": 100.0}}
    m = LayeredChain(SAMPLE, LayeredOptions(layers=[plate, {"name": "sample", "n_elements": 4}]))
    assert m.parameter_names == ["k_sigma_sample", "b_sigma_sample", "k_tau_sample", "b_tau_sample"]
    assert not m.exact_time_scaling
    area = np.pi * 0.0254**2 / 4
    vals = m.layer_values(np.ones(4))
    assert vals[0][0] == pytest.approx(5.6e9 * area / 0.003, rel=1e-14)  # k = E A / (L/n)
    assert vals[0][2] == 1e7
    assert vals[0][3] == pytest.approx(100.0 * np.pi * 0.0254, rel=1e-14)  # b_tau = eta_tau pi D
    mu_plate = 1180.0 * area * 0.003
    mu_sample = 1000.0 * area * 0.044 / 4
    np.testing.assert_allclose(m.masses(), [mu_plate / 2, mu_plate, (mu_plate + mu_sample) / 2,
                                            mu_sample, mu_sample, mu_sample / 2], rtol=1e-14)
    assert m.layers[1].sample.length == pytest.approx(0.044)


def test_per_layer_link_laws():
    m = LayeredChain(SAMPLE, LayeredOptions(layers=[
        {"name": "skin", "length": 0.005, "n_elements": 1, "link": "sls"},
        {"name": "flesh", "n_elements": 3, "link": "maxwell", "shear_link": "kelvin_voigt"}]))
    assert m.parameter_names == ["k_sigma_skin", "k1_sigma_skin", "b1_sigma_skin", "k_tau_skin", "k1_tau_skin",
                                 "b1_tau_skin", "k_sigma_flesh", "b_sigma_flesh", "k_tau_flesh", "b_tau_flesh"]
    # states: x, v (4 + 4), SLS normal + shear arm (1 + 1), Maxwell normal arms (3)
    assert m.n_states == 8 + 2 + 3
    assert "tau_sigma_skin" in m.derived_properties([p.typical for p in m.parameters])


@pytest.mark.parametrize("options,match", [
    ({"layers": [{"length": 0.02}, {"length": 0.02}]}, "add up to"),
    ({"layers": [{"length": 0.06}, {}]}, "leave nothing"),
    ({"shared": ["k_tao"], "layers": [{}]}, "did you mean 'k_tau'"),
    ({"layers": [{"fixed": {"E_sigm": 1.0}}]}, "did you mean 'E_sigma'"),
    ({"layers": [{"fixed": {"k_sigma": 1, "b_sigma": 1, "k_tau": 1, "b_tau": 1}}]}, "nothing left"),
])
def test_config_errors_name_the_key(options, match):
    with pytest.raises(ConfigError, match=match):
        LayeredChain(SAMPLE, LayeredOptions.model_validate(options))


@pytest.mark.parametrize("options", [
    {"layers": []},
    {"layers": [{"name": "a"}, {"name": "a"}]},
    {"layers": [{}, {}]},
    {"layers": [{"name": "bad name"}]},
    {"layers": [{"thickness": 0.01}]},
])
def test_options_validation(options):
    from pydantic import ValidationError

    with pytest.raises(ValidationError):
        LayeredOptions.model_validate(options)


def test_sample_behind_known_plates_is_recovered():
    """Acrylic coupling plates with fixed properties on both sides of a 3.8 cm sample."""
    plate = {"length": 0.006, "density": 1180.0, "n_elements": 1,
             "fixed": {"E_sigma": 5.6e9, "eta_sigma": 200.0, "E_tau": 1.0e9, "eta_tau": 500.0}}
    m = LayeredChain(SAMPLE, LayeredOptions(layers=[{"name": "front", **plate}, {"name": "sample", "n_elements": 6},
                                                     {"name": "back", **plate}]))
    truth = np.array([3e8, 15.0, 5e7, 12.0])
    w = Prbs(PrbsOptions(order=9, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=2000)).waveform()
    y0 = simulate(m, truth, w.u, w.dt)
    y = y0 + np.random.default_rng(4).normal(0, 0.05 * np.sqrt(np.mean(y0**2)), y0.shape)
    opts = ScipyLMOptions.model_validate({"strategy": {"n_starts": 1, "bands": [], "time_scale": False}})
    fit = ScipyLM(opts).solve(FitProblem(m, w.t, w.u, y, initial=truth * np.array([1.05, 0.95, 0.96, 1.04])))
    unc = from_jacobian(m.parameter_names, fit.jacobian, fit.cost)
    assert np.all(np.abs(fit.theta - truth) < 3 * unc.standard_errors)


def test_example_config_runs_end_to_end(tmp_path):
    """examples/configs/layered_plates.yaml: plates fixed by their properties, sample estimated."""
    from pathlib import Path

    from mbus_framework.pipeline.run import execute

    config = Path(__file__).resolve().parents[1] / "examples" / "configs" / "layered_plates.yaml"
    outcome = execute(config, out_dir=tmp_path / "run", plots=False)
    props = outcome.result["properties"]
    truth = {"E_sigma_sample": 2.2e9, "eta_sigma_sample": 1.0e3, "E_tau_sample": 1.0e8, "eta_tau_sample": 8.0e2}
    for name, value in truth.items():
        assert props[name] == pytest.approx(value, rel=0.05), name
    assert outcome.components.model.parameter_names == [
        "k_sigma_sample", "b_sigma_sample", "k_tau_sample", "b_tau_sample"]
