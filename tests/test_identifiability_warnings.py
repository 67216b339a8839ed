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
