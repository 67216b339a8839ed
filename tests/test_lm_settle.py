"""The final local solve's statistical stop (:func:`mbus_framework.estimation.local.settled`):
the Gauss-Newton minimum within a fraction of the standard errors, checked against a linear
least-squares problem solved exactly, and a settled fit's estimate against a run to MINPACK's
own tolerances."""
from __future__ import annotations

import numpy as np

from mbus_framework.estimation.local import lm_fit, settled
from tests.test_scipy_lm import TABLE_3_1, table_like


def _linear(rng, n=400, k=3, sigma=0.1):
    J = rng.normal(size=(n, k))
    beta = rng.normal(size=k)
    y = J @ beta + rng.normal(0.0, sigma, n)
    return J, y


def test_settled_is_the_mahalanobis_distance_to_the_least_squares_solution():
    """m = sqrt(d^T J^T J d) / sigma with d the exact least-squares step and
    sigma^2 = ||r||^2 / (N - p): settled exactly when m < fraction."""
    rng = np.random.default_rng(3)
    J, y = _linear(rng)
    best, *_ = np.linalg.lstsq(J, y, rcond=None)
    cov = np.linalg.inv(J.T @ J)
    for offset in (1e-4, 0.03, 0.2, 2.0):  # in standard errors along a random direction
        direction = rng.normal(size=3)
        r_best = J @ best - y
        sigma = np.sqrt(r_best @ r_best / (J.shape[0] - 3))
        step = direction / np.sqrt(direction @ (J.T @ J) @ direction) * sigma * offset
        x = best + step
        r = J @ x - y
        s2 = r @ r / (J.shape[0] - 3)
        d = best - x
        m = np.sqrt(d @ (J.T @ J) @ d / s2)
        assert np.isclose(m, offset, rtol=0.05)
        for fraction in (0.01, 0.05, 0.5):
            if abs(m - fraction) > 1e-6:
                assert settled(J, r, fraction) == (m < fraction)
        # every parameter's move is bounded by m standard errors
        assert np.all(np.abs(d) <= m * np.sqrt(s2 * np.diag(cov)) * (1 + 1e-9))


def test_a_rank_deficient_jacobian_settles_on_what_it_can_resolve():
    rng = np.random.default_rng(4)
    J, y = _linear(rng)
    J = np.column_stack([J, J[:, 0]])  # a fourth column no record can tell from the first
    best, *_ = np.linalg.lstsq(J, y, rcond=None)
    assert settled(J, J @ best - y, 0.05)
    assert not settled(J, J @ (best + 1.0) - y, 0.05)
    assert not settled(np.zeros_like(J), y, 0.05)  # no information: never settled


def test_a_settled_final_solve_ends_within_a_small_fraction_of_a_standard_error():
    """From a start off the minimum, the settled solve's estimate differs from the solve run to
    MINPACK's tolerances by less than 0.05 standard errors in every parameter."""
    problem = table_like()
    start = TABLE_3_1 * np.array([1.3, 0.8, 1.2, 0.9])
    full = lm_fit(problem, start, None, 400, True, stop_se=None)
    quick = lm_fit(problem, start, None, 400, True)
    assert "standard errors" in quick.message and quick.nfev < full.nfev  # the statistical stop ended it
    yhat, J = problem.predict_with_jacobian(full.theta)
    r = problem.y - yhat
    cov = np.linalg.inv(J.T @ J) * float(r @ r) / (r.size - J.shape[1])
    se = np.sqrt(np.diag(cov))
    assert np.all(np.abs(quick.theta - full.theta) < 0.05 * se)
    assert quick.cost <= full.cost + 0.05**2 * float(r @ r) / (r.size - J.shape[1])
