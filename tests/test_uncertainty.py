"""Linearised uncertainty: exact for linear regression, consistent with Monte Carlo for the
Kelvin-Voigt fit, delta method for the material properties."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import least_squares

from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import simulate
from mbus_framework.estimation.problem import FitProblem
from mbus_framework.estimation.uncertainty import from_jacobian, property_covariance
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions


def regression(rng, n=200, scales=(1.0, 1.0, 1.0)):
    x = np.linspace(-1, 1, n)
    X = np.column_stack([np.ones(n), x, x**2]) * np.asarray(scales)
    beta = np.array([1.0, -2.0, 0.5]) / np.asarray(scales)
    y = X @ beta + rng.normal(0.0, 0.3, n)
    bhat, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ bhat
    return X, y, bhat, 0.5 * float(r @ r)


def assert_cov_close(actual, expected, tol=1e-8):
    """Entry-wise agreement relative to sqrt(C_ii C_jj) (zero covariances compare absolutely)."""
    se = np.sqrt(np.diag(expected))
    np.testing.assert_allclose(actual / np.outer(se, se), expected / np.outer(se, se), rtol=0, atol=tol)


@pytest.mark.parametrize("scales", [(1.0, 1.0, 1.0), (1e-6, 1e3, 1e9)])
def test_linear_regression_matches_the_textbook_formula(scales):
    """OLS: Cov = s^2 (X^T X)^-1 with s^2 = RSS / (n - p), also for columns of wildly mixed scale."""
    X, y, bhat, cost = regression(np.random.default_rng(0), scales=scales)
    n, p = X.shape
    s2 = 2 * cost / (n - p)
    cov = s2 * np.linalg.inv(X.T @ X)
    unc = from_jacobian(["a", "b", "c"], X, cost)
    assert_cov_close(unc.covariance, cov)
    np.testing.assert_allclose(unc.standard_errors, np.sqrt(np.diag(cov)), rtol=1e-8)
    np.testing.assert_allclose(np.diag(unc.correlation), 1.0, rtol=1e-12)
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    np.testing.assert_allclose(unc.correlation, corr, atol=1e-10)
    assert unc.dof == n - p
    assert unc.residual_std == pytest.approx(np.sqrt(s2), rel=1e-12)
    # 95 % intervals with Student's t, n - p degrees of freedom.
    q = stats.t.ppf(0.975, n - p)
    ci = unc.intervals(bhat)
    np.testing.assert_allclose(ci[:, 0], bhat - q * unc.standard_errors, rtol=1e-12)
    np.testing.assert_allclose(ci[:, 1], bhat + q * unc.standard_errors, rtol=1e-12)
    np.testing.assert_allclose(unc.relative_standard_errors(bhat), unc.standard_errors / np.abs(bhat), rtol=1e-12)


def test_known_noise_variance():
    X, y, bhat, cost = regression(np.random.default_rng(1))
    unc = from_jacobian(["a", "b", "c"], X, cost, scale=0.09)
    assert_cov_close(unc.covariance, 0.09 * np.linalg.inv(X.T @ X))


def test_monte_carlo_coverage_of_linear_regression():
    """Over 2000 noise realisations the empirical covariance of the estimates matches the
    predicted one, and the 95 % intervals cover the truth about 95 % of the time."""
    rng = np.random.default_rng(2)
    n = 60
    x = np.linspace(0, 1, n)
    X = np.column_stack([np.ones(n), x])
    beta = np.array([0.3, 1.7])
    estimates, covered = [], []
    for _ in range(2000):
        y = X @ beta + rng.normal(0, 0.2, n)
        bhat, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ bhat
        unc = from_jacobian(["a", "b"], X, 0.5 * float(r @ r))
        ci = unc.intervals(bhat)
        covered.append((ci[:, 0] <= beta) & (beta <= ci[:, 1]))
        estimates.append(bhat)
    estimates = np.array(estimates)
    predicted = 0.04 * np.linalg.inv(X.T @ X)
    np.testing.assert_allclose(np.cov(estimates.T), predicted, rtol=0.1, atol=0.1 * np.abs(predicted).max())
    coverage = np.mean(covered, axis=0)
    assert np.all(np.abs(coverage - 0.95) < 0.015), coverage  # binomial SE 0.5 %


def test_rank_deficient_jacobian_reports_unidentifiable_directions():
    """Directions the data cannot see get huge or infinite standard errors, never small ones
    (a pseudo-inverse would silently drop them and report the rest as precise)."""
    J = np.column_stack([np.ones(10), np.ones(10), np.arange(10.0)])
    unc = from_jacobian(["a", "b", "c"], J, 1.0)
    assert np.all(unc.standard_errors[:2] > 1e6)  # a and b only enter as a + b
    assert unc.condition < 1e-12
    full_rank = from_jacobian(["ab", "c"], np.column_stack([np.ones(10), np.arange(10.0)]), 1.0, scale=0.1)
    same_scale = from_jacobian(["a", "b", "c"], J, 1.0, scale=0.1)
    assert same_scale.standard_errors[2] == pytest.approx(full_rank.standard_errors[1], rel=1e-9)
    zero = np.column_stack([np.ones(10), np.zeros(10)])
    unc = from_jacobian(["a", "b"], zero, 1.0)
    assert np.isinf(unc.standard_errors[1]) and np.isfinite(unc.standard_errors[0])
    assert np.all(np.isfinite(unc.correlation))


def test_kelvin_voigt_standard_errors_match_monte_carlo():
    """40 noise realisations of a small Kelvin-Voigt case, each fitted locally from the truth:
    the spread of the estimates matches the linearised standard errors (std of a 40-sample
    std estimate is ~11 %, so the band 0.6-1.5 is generous but still catches a wrong s^2 or a
    missing column scaling)."""
    model = KelvinVoigtChain(Sample(0.02, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=4))
    truth = model.from_properties({"E_sigma": 2e9, "eta_sigma": 300.0, "E_tau": 4e8, "eta_tau": 500.0})
    w = Prbs(PrbsOptions(order=9, bit_width=1e-6, sample_rate=10e6, n_samples=1500)).waveform()
    y0 = simulate(model, truth, w.u, w.dt)
    sigma = 0.1 * np.sqrt(np.mean(y0**2))
    rng = np.random.default_rng(4)
    estimates, ses = [], []
    for _ in range(40):
        problem = FitProblem(model, w.t, w.u, y0 + rng.normal(0, sigma, y0.size))

        def residual(phi):
            return problem.predict(np.exp(phi)) - problem.y

        def jac(phi):
            _, J = problem.predict_with_jacobian(np.exp(phi))
            return J * np.exp(phi)

        res = least_squares(residual, np.log(truth), jac=jac, method="lm", xtol=1e-12, ftol=1e-12)
        theta = np.exp(res.x)
        _, J = problem.predict_with_jacobian(theta)
        unc = from_jacobian(problem.names, J, res.cost)
        estimates.append(theta)
        ses.append(unc.standard_errors)
        assert unc.residual_std == pytest.approx(sigma, rel=0.1)
    estimates, ses = np.array(estimates), np.array(ses)
    ratio = estimates.std(axis=0, ddof=1) / ses.mean(axis=0)
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio
    # Unbiased to within the Monte Carlo error.
    assert np.all(np.abs(estimates.mean(axis=0) - truth) < 4 * ses.mean(axis=0) / np.sqrt(40))


def test_property_covariance_is_the_delta_method_of_eqs_3_32_to_3_38():
    model = KelvinVoigtChain(Sample(0.05, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=10))
    theta = np.array([3e8, 15.0, 5e7, 12.0])
    rng = np.random.default_rng(5)
    A = rng.normal(size=(4, 4))
    cov = A @ A.T * np.outer(theta, theta) * 1e-4
    names, values, pcov = property_covariance(model.to_properties, theta, np.ones(4, bool), cov)
    assert names == ["E_sigma", "eta_sigma", "E_tau", "eta_tau"]
    f = model.sample.length / 10 / model.sample.area
    c = 1 / model.sample.circumference
    G = np.diag([f, f, c, c])  # the properties are linear in the parameters
    np.testing.assert_allclose(pcov, G @ cov @ G.T, rtol=1e-6)
    np.testing.assert_allclose(values, [model.to_properties(theta)[n] for n in names], rtol=1e-14)
    # Only the free parameters' columns: fixing b_tau removes eta_tau's variance.
    free = np.array([True, True, True, False])
    _, _, pcov3 = property_covariance(model.to_properties, theta, free, cov[:3, :3])
    np.testing.assert_allclose(pcov3[:3, :3], (G @ cov @ G.T)[:3, :3], rtol=1e-6)
    assert pcov3[3, 3] == 0.0
