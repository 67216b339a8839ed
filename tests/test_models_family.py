"""Maxwell, SLS and generalized-Maxwell chains: limits, properties, initial values, truth recovery."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mbus_framework.interfaces.excitation import Waveform
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
DT = 1 / 6.25e6


def prbs(n_samples: int) -> Waveform:
    """Fig. 3.7 setting 1: 2.5 us bits at 6.25 MS/s."""
    return Prbs(PrbsOptions(order=9, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=n_samples)).waveform()


def rel_max(a, b) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


U = prbs(1500).u


# -- cross-model limits ------------------------------------------------------------------------

params = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))


@settings(max_examples=12)
@given(n=st.integers(1, 8), logs=params)
def test_sls_with_stiff_arm_spring_is_kelvin_voigt(n, logs):
    """k1 -> inf: the Maxwell arm becomes its dashpot, SLS(k, k1, b1) -> KV(k, b1)."""
    k_s, b_s, k_t, b_t = np.array([3e8, 15.0, 5e7, 12.0]) * np.exp(logs)
    # arm relaxation time b1/k1 = 1e-6 of a sample interval: far above the record's band
    k1_s, k1_t = b_s / (1e-6 * DT), b_t / (1e-6 * DT)
    kv = KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n))
    sls = SlsChain(SAMPLE, SlsOptions(n_elements=n))
    y_kv = simulate(kv, [k_s, b_s, k_t, b_t], U, DT)
    y_sls = simulate(sls, [k_s, k1_s, b_s, k_t, k1_t, b_t], U, DT)
    assert rel_max(y_sls, y_kv) < 1e-6


@settings(max_examples=12)
@given(n=st.integers(1, 8), logs=params)
def test_maxwell_with_stiff_dashpot_is_a_spring_chain(n, logs):
    """b -> inf: the Maxwell link becomes its spring: KV chain with zero damping."""
    k_s, _, k_t, _ = np.array([3e8, 15.0, 5e7, 12.0]) * np.exp(logs)
    big = 1e8 * k_s * (1500 * DT)  # relaxation time 1e8 record lengths
    mx = MaxwellChain(SAMPLE, MaxwellOptions(n_elements=n))
    kv = KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n))
    y_spring = simulate(kv, [k_s, 0.0, k_t, 0.0], U, DT)
    assert rel_max(simulate(mx, [k_s, big, k_t, big], U, DT), y_spring) < 1e-6


@settings(max_examples=12)
@given(n=st.integers(1, 8), logs=params)
def test_sls_with_stiff_arm_dashpot_is_a_spring_chain(n, logs):
    """b1 -> inf: the arm never relaxes, SLS(k, k1, b1) -> spring k + k1."""
    k_s, k1_s, k_t, k1_t = np.array([2e8, 1e8, 4e7, 1e7]) * np.exp(logs)
    big = 1e8 * (k_s + k1_s) * (1500 * DT)
    sls = SlsChain(SAMPLE, SlsOptions(n_elements=n))
    kv = KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n))
    y_spring = simulate(kv, [k_s + k1_s, 0.0, k_t + k1_t, 0.0], U, DT)
    assert rel_max(simulate(sls, [k_s, k1_s, big, k_t, k1_t, big], U, DT), y_spring) < 1e-6


def test_generalized_maxwell_arms_are_interchangeable():
    gm = GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=4, n_arms=2))
    theta = np.array([2e8, 6e7, 60.0, 4e7, 400.0, 5e7, 12.0])
    swapped = theta[[0, 3, 4, 1, 2, 5, 6]]
    poles = np.sort_complex(np.linalg.eigvals(gm.state_space(theta).A))
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(gm.state_space(swapped).A)), poles, rtol=1e-9)
    y = simulate(gm, theta, U[:500], DT)
    assert rel_max(simulate(gm, swapped, U[:500], DT), y) < 1e-9
    np.testing.assert_array_equal(swapped[gm.canonical_order(swapped)], theta)
    np.testing.assert_array_equal(gm.canonical_order(theta), np.arange(7))


@settings(max_examples=10)
@given(n=st.integers(1, 12), logs=st.lists(st.floats(-2, 2), min_size=6, max_size=6))
def test_one_arm_generalized_maxwell_is_sls_exactly(n, logs):
    theta = np.array([2e8, 1e8, 300.0, 4e7, 1e7, 100.0]) * np.exp(logs)
    gm = GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=n, n_arms=1,
                                                                   shear_link="generalized_maxwell"))
    sls = SlsChain(SAMPLE, SlsOptions(n_elements=n))
    for a, b in zip(gm.state_space(theta), sls.state_space(theta)):
        np.testing.assert_array_equal(a, b)
    assert gm.to_properties(theta) == sls.to_properties(theta)


# -- names, properties, derived quantities ----------------------------------------------------


def test_parameter_and_property_names():
    assert MaxwellChain(SAMPLE, MaxwellOptions()).parameter_names == ["k_sigma", "b_sigma", "k_tau", "b_tau"]
    sls = SlsChain(SAMPLE, SlsOptions())
    assert sls.parameter_names == ["k_sigma", "k1_sigma", "b1_sigma", "k_tau", "k1_tau", "b1_tau"]
    assert sls.property_names == ["E_sigma", "E1_sigma", "eta1_sigma", "E_tau", "E1_tau", "eta1_tau"]
    gm = GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_arms=3))
    assert gm.parameter_names == ["k_sigma", "k1_sigma", "b1_sigma", "k2_sigma", "b2_sigma", "k3_sigma",
                                  "b3_sigma", "k_tau", "b_tau"]
    units = {p.name: p.unit for p in gm.parameters}
    assert units["k2_sigma"] == "N/m" and units["b2_sigma"] == "N s/m"
    assert {p.name: p.time_exponent for p in sls.parameters} == {
        "k_sigma": 2, "k1_sigma": 2, "b1_sigma": 1, "k_tau": 2, "k1_tau": 2, "b1_tau": 1}
    assert all(p.lower == 0 and p.upper == np.inf for p in gm.parameters)


def test_property_conversion_follows_eqs_3_32_to_3_38():
    n = 10
    sls = SlsChain(SAMPLE, SlsOptions(n_elements=n))
    theta = np.array([2e8, 1e8, 300.0, 4e7, 1e7, 100.0])
    g = (SAMPLE.length / n) / (np.pi * SAMPLE.diameter**2 / 4)
    c = np.pi * SAMPLE.diameter
    props = sls.to_properties(theta)
    assert props["E_sigma"] == pytest.approx(g * 2e8, rel=1e-14)
    assert props["eta1_sigma"] == pytest.approx(g * 300.0, rel=1e-14)
    assert props["E1_tau"] == pytest.approx(1e7 / c, rel=1e-14)
    derived = sls.derived_properties(theta)
    assert derived["tau_sigma"] == pytest.approx(300.0 / 1e8)
    assert derived["tau_tau"] == pytest.approx(100.0 / 1e7)
    assert derived["E0_sigma"] == pytest.approx(props["E_sigma"] + props["E1_sigma"])
    mx = MaxwellChain(SAMPLE, MaxwellOptions(n_elements=n))
    d = mx.derived_properties([3e8, 900.0, 5e7, 500.0])
    assert d["tau_sigma"] == pytest.approx(3e-6) and d["tau_tau"] == pytest.approx(1e-5)
    p = mx.to_properties([3e8, 900.0, 5e7, 500.0])
    assert d["tau_sigma"] == pytest.approx(p["eta_sigma"] / p["E_sigma"])


@pytest.mark.parametrize("model,truth", [
    (MaxwellChain(SAMPLE, MaxwellOptions(n_elements=8)), [3e8, 900.0, 5e7, 500.0]),
    (SlsChain(SAMPLE, SlsOptions(n_elements=8)), [2e8, 1e8, 300.0, 4e7, 1e7, 100.0]),
    (GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=8)), [2e8, 6e7, 60.0, 4e7, 400.0, 5e7, 12.0]),
])
def test_initial_guess_finds_the_wave_speed(model, truth):
    """The guess's unrelaxed wave crosses the sample in the measured first-arrival time, and its
    unrelaxed normal stiffness is within a factor 4 of the truth (the arrival of a dispersive,
    relaxing medium lies between its relaxed and unrelaxed speeds)."""
    from mbus_framework.engine.physics import first_arrival_time

    w = prbs(3000)
    y = simulate(model, truth, w.u, w.dt)
    y = y + np.random.default_rng(0).normal(0, 0.05 * np.std(y), y.shape)
    guess = model.initial_guess(w.t, w.u, y)
    t_arr = first_arrival_time(w.t, w.u, y)
    assert SAMPLE.length / model.wave_speed(guess) == pytest.approx(t_arr, rel=1e-9)
    law = model.normal_law()
    k_true = law.instantaneous_stiffness(truth[: len(law.parameters)])
    k_guess = law.instantaneous_stiffness(guess[: len(law.parameters)])
    assert 0.25 < k_guess / k_true < 4.0
    e = np.array([p.time_exponent for p in model.parameters])
    typical = np.array([p.typical for p in model.parameters])
    ratio = guess / typical  # a pure time-scale move: ratio = c**e for one c
    c = np.sqrt(ratio[0])
    np.testing.assert_allclose(ratio, c**e, rtol=1e-12)


# -- truth recovery ---------------------------------------------------------------------------

FAST_LM = ScipyLMOptions.model_validate({"strategy": {"n_starts": 1, "bands": [], "time_scale": False}})

RECOVERY = {
    "kelvin_voigt": (KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=6)), [3e8, 15.0, 5e7, 12.0]),
    "maxwell": (MaxwellChain(SAMPLE, MaxwellOptions(n_elements=6)), [3e8, 900.0, 5e7, 500.0]),
    "sls": (SlsChain(SAMPLE, SlsOptions(n_elements=6)), [2e8, 1e8, 300.0, 4e7, 1e7, 100.0]),
    "generalized_maxwell": (GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=6)),
                            [2e8, 6e7, 60.0, 4e7, 400.0, 5e7, 12.0]),
    "layered": (LayeredChain(SAMPLE, LayeredOptions(layers=[
        {"name": "skin", "length": 0.02, "n_elements": 2},
        {"name": "flesh", "n_elements": 4, "density": 1100.0}])),
        [2e8, 10.0, 5e7, 12.0, 4e8, 20.0, 3e7, 8.0]),
}


def simulated_record(model, truth, n_samples=2000, noise=0.05, seed=0):
    w = prbs(n_samples)
    y0 = simulate(model, truth, w.u, w.dt)
    rng = np.random.default_rng(seed)
    return w, y0 + rng.normal(0, noise * np.sqrt(np.mean(y0**2)), y0.shape)


@pytest.mark.parametrize("name", list(RECOVERY))
def test_truth_recovery_within_three_standard_errors(name):
    """Each model identifies data it generated (5 % noise): |estimate - truth| < 3 SE for all."""
    model, truth = RECOVERY[name]
    truth = np.asarray(truth, float)
    w, y = simulated_record(model, truth)
    start = truth * np.exp(np.random.default_rng(1).uniform(-0.05, 0.05, truth.size))
    fit = ScipyLM(FAST_LM).solve(FitProblem(model, w.t, w.u, y, initial=start))
    unc = from_jacobian(model.parameter_names, fit.jacobian, fit.cost)
    z = (fit.theta - truth) / unc.standard_errors
    assert fit.success
    assert np.all(np.abs(z) < 3.0), dict(zip(model.parameter_names, np.round(z, 2)))
    assert np.all(unc.standard_errors / truth < 0.5)  # informative data, not vacuous error bars


@pytest.mark.slow
@pytest.mark.parametrize("name", list(RECOVERY))
def test_truth_recovery_from_physics_initial_values(name):
    """The lead's global strategy from each model's own initial_guess, default options."""
    model, truth = RECOVERY[name]
    truth = np.asarray(truth, float)
    w, y = simulated_record(model, truth, n_samples=3000, seed=2)
    fit = ScipyLM(ScipyLMOptions()).solve(FitProblem(model, w.t, w.u, y))
    unc = from_jacobian(model.parameter_names, fit.jacobian, fit.cost)
    # generalized Maxwell arms are interchangeable: compare in relaxation-time order
    idx = model.canonical_order(fit.theta) if hasattr(model, "canonical_order") else np.arange(truth.size)
    z = (fit.theta[idx] - truth) / unc.standard_errors[idx]
    assert np.all(np.abs(z) < 3.0), dict(zip(model.parameter_names, np.round(z, 2)))
