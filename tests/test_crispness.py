"""Chapter 7 statistics: agreement and its tests against scipy, Fisher's Z and the dependent
correlation test (size under H0), parallel-line tests against Kleinbaum's pooled formula,
sensitivities on known functions, leave-one-out, structure comparison."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from sklearn.base import clone
from sklearn.linear_model import LinearRegression

from mbus_framework.analysis.crispness.agreement import agreement, compare_lines, dependent_correlation_test, fisher_z_test
from mbus_framework.analysis.crispness.validation import (
    fold_seeds, leave_one_out, rank, recommend_structure, ridge_baseline, sensitivities, structure_comparison,
)
from mbus_framework.analysis.crispness.regressor import LMNetworkRegressor
from mbus_framework.analysis.crispness.virtual_panel import LogisticRelation


def test_agreement_against_scipy_linregress():
    rng = np.random.default_rng(0)
    x = rng.uniform(1, 8, 40)
    y = 0.4 + 0.9 * x + rng.normal(0, 0.5, 40)
    a = agreement(x, y)
    lr = stats.linregress(x, y)
    assert a.r == pytest.approx(lr.rvalue, rel=1e-12) and a.r_p == pytest.approx(lr.pvalue, rel=1e-9)
    assert a.slope == pytest.approx(lr.slope, rel=1e-12) and a.intercept == pytest.approx(lr.intercept, rel=1e-12)
    assert a.slope_se == pytest.approx(lr.stderr, rel=1e-10) and a.intercept_se == pytest.approx(lr.intercept_stderr, rel=1e-10)
    t_b = (lr.slope - 1) / lr.stderr
    assert a.slope_t == pytest.approx(t_b, rel=1e-10)
    assert a.slope_p == pytest.approx(2 * stats.t.sf(abs(t_b), 38), rel=1e-10)
    assert a.intercept_p == pytest.approx(2 * stats.t.sf(abs(lr.intercept / lr.intercept_stderr), 38), rel=1e-10)
    assert a.rmse == pytest.approx(np.sqrt(np.mean((y - x) ** 2)))


def test_fisher_z_by_hand_and_its_size_under_h0():
    t = fisher_z_test(0.9197, 46, 0.9691, 46)  # the dissertation's two correlations
    z = (np.arctanh(0.9197) - np.arctanh(0.9691)) / np.sqrt(2 / 43)
    assert t["z"] == pytest.approx(z, rel=1e-12) and t["p"] == pytest.approx(2 * stats.norm.sf(abs(z)), rel=1e-12)
    # two independent samples with the same rho: the test rejects at its nominal rate
    rng = np.random.default_rng(1)
    n, reps = 30, 3000
    r = correlations(rng, np.array([[1, 0.7], [0.7, 1]]), n, 2 * reps)
    p = np.array([fisher_z_test(a, n, b, n)["p"] for a, b in r[:, 0, 1].reshape(reps, 2)])
    assert np.mean(p < 0.05) == pytest.approx(0.05, abs=0.015)


def correlations(rng, cov, n, reps) -> np.ndarray:
    """Sample correlation matrices of ``reps`` normal samples of size n with covariance cov."""
    d = rng.standard_normal((reps, n, len(cov))) @ np.linalg.cholesky(cov).T
    d = d - d.mean(axis=1, keepdims=True)
    c = np.einsum("rni,rnj->rij", d, d)
    s = np.sqrt(np.einsum("rii->ri", c))
    return c / s[:, :, None] / s[:, None, :]


def test_dependent_correlation_test_size_and_power():
    """y and two predictors with equal true correlation to y (H0) but correlated with each
    other: rejection near the nominal 5 %. With unequal correlations the test has power."""
    rng = np.random.default_rng(2)
    n, reps = 40, 2000

    def rejection(r1, r2, r12):
        c = correlations(rng, np.array([[1, r1, r2], [r1, 1, r12], [r2, r12, 1]]), n, reps)
        p = [dependent_correlation_test(m[0, 1], m[0, 2], m[1, 2], n)["p"] for m in c]
        return np.mean(np.array(p) < 0.05)

    assert rejection(0.6, 0.6, 0.8) == pytest.approx(0.05, abs=0.02)
    assert rejection(0.7, 0.4, 0.6) > 0.6


def test_parallel_lines_against_the_pooled_formula():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 9, 35)
    p1, p2 = 0.3 + 0.95 * x + rng.normal(0, 0.4, 35), 1.0 + 0.8 * x + rng.normal(0, 0.6, 35)
    c = compare_lines(x, p1, p2)
    fits = [LinearRegression().fit(x[:, None], p) for p in (p1, p2)]
    sse = sum(((p - f.predict(x[:, None])) ** 2).sum() for p, f in zip((p1, p2), fits))
    s2 = sse / (2 * 35 - 4)
    sxx = ((x - x.mean()) ** 2).sum()
    t_slope = (fits[1].coef_[0] - fits[0].coef_[0]) / np.sqrt(s2 * 2 / sxx)
    t_icpt = (fits[1].intercept_ - fits[0].intercept_) / np.sqrt(s2 * 2 * (1 / 35 + x.mean() ** 2 / sxx))
    assert c["slope_t"] == pytest.approx(t_slope, rel=1e-10)
    assert c["intercept_t"] == pytest.approx(t_icpt, rel=1e-10)
    assert c["df"] == 66 and c["slope_p"] == pytest.approx(2 * stats.t.sf(abs(t_slope), 66), rel=1e-10)


def test_sensitivities_of_a_known_function():
    """f = 2 x0 + x1^2 - 0 x2: a +10 % change moves f by 0.2 x0 and 0.21 x1^2 exactly."""
    rng = np.random.default_rng(4)
    X = rng.uniform(1, 3, (25, 3))
    s = sensitivities(lambda Z: 2 * Z[:, 0] + Z[:, 1] ** 2, X, ["a", "b", "c"], 0.1)
    np.testing.assert_allclose(s.loc["a", "mean_abs_change"], np.mean(0.2 * X[:, 0]), rtol=1e-12)
    np.testing.assert_allclose(s.loc["b", "mean_abs_change"], np.mean(0.21 * X[:, 1] ** 2), rtol=1e-12)
    np.testing.assert_allclose(s.loc["b", "sd_abs_change"], np.std(0.21 * X[:, 1] ** 2, ddof=1), rtol=1e-12)
    assert s.loc["c", "mean_abs_change"] == 0.0
    neg = sensitivities(lambda Z: -Z[:, 0], X, ["a", "b", "c"])
    assert neg.loc["a", "mean_change"] == pytest.approx(-neg.loc["a", "mean_abs_change"])


def test_logistic_relation_sensitivities_and_effect_order():
    rel = LogisticRelation({"E": 2.0, "G": 0.5, "eta": -1.0}, {"E": 1.0, "G": 1.0, "eta": 1.0}, intercept=0.1)
    rng = np.random.default_rng(5)
    values = {k: rng.uniform(0.5, 2, 30) for k in ("E", "G", "eta")}
    X = np.column_stack([values[k] for k in ("E", "G", "eta")])
    ours = sensitivities(lambda Z: rel(dict(zip(("E", "G", "eta"), Z.T))), X, ["E", "G", "eta"])
    for k, (mean, sd) in rel.sensitivities(values).items():
        assert ours.loc[k, "mean_abs_change"] == pytest.approx(mean, rel=1e-12)
        assert ours.loc[k, "sd_abs_change"] == pytest.approx(sd, rel=1e-12)
    assert rel.effect_order(values) == ["E", "eta", "G"] == rank(ours)
    assert rel({"E": [1.0], "G": [1.0], "eta": [1.0]})[0] == pytest.approx(9 / (1 + np.exp(-0.1)))


def test_leave_one_out_is_reproducible_and_order_free():
    rng = np.random.default_rng(6)
    X = rng.random((12, 2))
    y = np.sin(3 * X[:, 0]) + X[:, 1]
    est = LMNetworkRegressor((2,), n_restarts=1, n_members=1, max_epochs=40)
    a = leave_one_out(est, X, y, seed=3).predictions
    b = leave_one_out(est, X, y, seed=3).predictions
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=0)  # same seeds: same folds, to rounding
    # fold k depends only on its own seed: refit fold 5 by hand
    k = 5
    rest = np.delete(np.arange(12), k)
    own = clone(est).set_params(random_state=fold_seeds(3, 12)[k]).fit(X[rest], y[rest]).predict(X[k : k + 1])
    assert own[0] == pytest.approx(a[k], rel=1e-9)
    assert np.max(np.abs(a - leave_one_out(est, X, y, seed=4).predictions)) > 1e-6


def test_ridge_leave_one_out_matches_a_manual_loop():
    rng = np.random.default_rng(7)
    X = rng.random((15, 3)) * [1e10, 1e3, 1e9]
    y = X @ [1e-10, 1e-3, 2e-9] + rng.normal(0, 0.1, 15)
    loo = leave_one_out(ridge_baseline(), X, y).predictions
    manual = [ridge_baseline().fit(np.delete(X, k, 0), np.delete(y, k)).predict(X[k : k + 1])[0] for k in range(15)]
    np.testing.assert_allclose(loo, manual, rtol=1e-12)


def test_recommend_structure_is_the_smallest_within_one_standard_error():
    t = pd.DataFrame({
        "structure": ["2", "4", "6", "3-3"], "layers": [1, 1, 1, 2], "weights": [9, 17, 25, 25],
        "loo_mse": [0.40, 0.22, 0.20, 0.19], "loo_mse_se": [0.05, 0.04, 0.03, 0.04],
    })
    assert t.loc[recommend_structure(t), "structure"] == "4"  # 0.22 <= 0.19 + 0.04; fewer weights than 6
    t.loc[1, "loo_mse"] = 0.30
    assert t.loc[recommend_structure(t), "structure"] == "6"  # one layer before two


def test_structure_comparison_table_and_curves():
    rng = np.random.default_rng(8)
    X = rng.random((14, 2))
    y = X[:, 0] ** 2 + 0.5 * X[:, 1]
    base = LMNetworkRegressor(n_restarts=1, n_members=1, max_epochs=30)
    table, curves = structure_comparison(X, y, [(2,), (1, 1)], base, seed=0)
    assert list(table.structure) == ["2", "1-1"] and list(table.weights) == [9, 7]
    assert table.recommended.sum() == 1 and set(curves) == {"2", "1-1"}
    assert len(curves["2"]["train"]) >= 2 and np.all(np.isfinite(table.loo_mse))
