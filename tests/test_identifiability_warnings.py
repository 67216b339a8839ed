"""Warnings that mean something (issue 28): correlation is the shape of the uncertainty, not
its size, so a correlated group warns only when it is also imprecise, and then names the
combination the record determines.

The end-to-end records are Table 4.3 media simulated by scipy (``tests/test_global_minimum``):
liver at 5 % noise is correlated (k_sigma-k_tau |r| 0.97) but every SE is below 0.2 %;
water at 5 % noise trades k_sigma against k_tau at |r| ~ 1 with SEs of ~9 %.
"""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.api import fit
from mbus_framework.estimation.combinations import extreme_combinations
from mbus_framework.estimation.gate import information_gate
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from tests.test_global_minimum import CHAPTER4, chapter4, record


def test_the_ratio_of_a_tightly_correlated_pair_is_determined():
    """Independent reference: Var(ln a - ln b) = s_a^2 + s_b^2 - 2 r s_a s_b (relative SEs)."""
    values = np.array([3.0e9, 2.0e8])
    rel = np.array([0.08, 0.08])
    r = 0.9999
    cov = np.array([[1, r], [r, 1]]) * np.outer(rel * values, rel * values)
    best, worst = extreme_combinations(["k_sigma", "k_tau"], values, cov)
    assert best.expression == "k_sigma/k_tau"
    assert best.relative_se == pytest.approx(np.sqrt(2 * 0.08**2 * (1 - r)), rel=1e-9)
    assert worst.expression == "k_sigma*k_tau"
    assert worst.relative_se == pytest.approx(np.sqrt(2 * 0.08**2 * (1 + r)), rel=1e-9)


def test_unequal_errors_give_a_power_product():
    """With s_b = 2 s_a and r -> 1, ln a - ln b / 2 is what is fixed: a / b^0.5."""
    values = np.array([1.0, 1.0])
    rel = np.array([0.01, 0.02])
    r = 0.999999
    cov = np.array([[1, r], [r, 1]]) * np.outer(rel, rel)
    best, _ = extreme_combinations(["a", "b"], values, cov)
    assert best.expression == "a/b^0.5"
    a = np.array(best.exponents)
    assert best.relative_se == pytest.approx(np.sqrt(a @ cov @ a), rel=1e-12)
    assert best.relative_se < 1e-4


def test_no_combination_without_a_log_space():
    assert extreme_combinations(["gain", "delay"], np.array([1.0, 0.0]), np.eye(2)) is None


def _fit(name):
    model, theta = chapter4(name)
    problem, _ = record(model, theta, 9, 0.4e-6, 25e6, 6200, 0.05, seed=1, state=300)
    sample = dict(length=0.05, diameter=0.0254, density=CHAPTER4[name][0])
    return fit(problem.t, problem.u, problem.y, sample=sample, model_options={"n_elements": 10}, plots=False)


@pytest.mark.slow
def test_a_correlated_but_precise_fit_prints_no_warning():
    result = _fit("liver")
    unc = result.document["uncertainty"]
    assert max(unc["relative_standard_errors"].values()) < 0.005
    groups = unc["correlated_groups"]
    assert groups and max(g["max_correlation"] for g in groups) > 0.95  # correlated ...
    assert all(g["warning"] is None for g in groups)  # ... yet precise: nothing to act on
    assert result.warnings == [], result.warnings


@pytest.mark.slow
def test_an_imprecise_trade_off_warns_with_what_is_determined():
    result = _fit("water")
    unc = result.document["uncertainty"]
    assert max(unc["relative_standard_errors"][n] for n in ("k_sigma", "k_tau")) > 0.05
    warned = [w for w in result.warnings if "correlated" in w]
    assert len(warned) == 1 and "k_sigma/k_tau to" in warned[0] and "k_sigma*k_tau only to" in warned[0], warned
    group = next(g for g in unc["correlated_groups"] if g["warning"])
    # the ratio is known far better than either parameter, the product worse
    se = unc["relative_standard_errors"]
    assert group["best"]["relative_standard_error"] < 0.01 * min(se["k_sigma"], se["k_tau"])
    assert group["worst"]["relative_standard_error"] > max(se["k_sigma"], se["k_tau"])


# -- the information gate ----------------------------------------------------------------------
def _slow_potato(noise=0.05, seed=1):
    """Table 6.2 potato, E_sigma and E_tau at their minimum, eta_sigma at its maximum, eta_tau
    at its mean (30 mm, 10 elements), driven by a white +-1 input at 25 MS/s: its response
    arrives after ~350 samples, beyond the response test's 312 lags, smeared over hundreds."""
    model = KelvinVoigtChain(Sample(0.03, 0.0254, 1080.0), KelvinVoigtOptions(n_elements=10))
    theta = np.asarray(model.from_properties(dict(E_sigma=4.84e9, eta_sigma=3.83e4, E_tau=1.30e9, eta_tau=6.21e4)))
    problem, _ = record(model, theta, 10, 0.04e-6, 25e6, 5000, noise, seed=seed)
    return problem, theta


def test_a_precise_high_snr_fit_stands_for_the_response_test():
    problem, theta = _slow_potato()
    r = problem.y - problem.predict(theta)  # the residual of the truth: noise only
    blind = information_gate(problem.y, r, problem.u)
    assert blind["response_p_value"] > 1e-3 and not blind["reliable"]  # the model-free test misses it
    assert blind["signal_to_noise"] > 50
    shown = information_gate(problem.y, r, problem.u, relative_standard_errors=[0.003, 0.002, 0.003, 0.002])
    assert shown["reliable"] and shown["response_shown_by_fit"]
    # imprecise parameters, or a low signal-to-noise, do not stand for it
    assert not information_gate(problem.y, r, problem.u, relative_standard_errors=[0.003, 0.3, 0.003, 0.002])["reliable"]
    noise = np.random.default_rng(3).normal(0, np.std(problem.y), problem.y.size)
    assert not information_gate(noise, noise - 0.01 * noise.mean(), problem.u,
                                relative_standard_errors=[0.001] * 4)["reliable"]


@pytest.mark.slow
def test_a_slow_potato_fitted_to_the_noise_passes_the_gate():
    """The issue-28 case: recovered to a fraction of a percent at nrmse 0.05, no warning."""
    problem, theta = _slow_potato()
    result = fit(problem.t, problem.u, problem.y, sample=dict(length=0.03, diameter=0.0254, density=1080.0),
                 model_options={"n_elements": 10}, plots=False)
    doc = result.document
    est = np.array([doc["parameters"][n] for n in ("k_sigma", "b_sigma", "k_tau", "b_tau")])
    rse = np.array([doc["uncertainty"]["relative_standard_errors"][n] for n in ("k_sigma", "b_sigma", "k_tau", "b_tau")])
    assert np.all(np.abs(est / theta - 1) < 4 * rse) and np.all(rse < 0.01)
    assert doc["fit"]["information"]["response_p_value"] > 1e-3  # the model-free test alone would fire
    assert doc["fit"]["reliable"] is True
    assert result.warnings == [], result.warnings
