"""``scipy_lm`` solver: the common FitResult contract, fixed parameters, Jacobian options, and why
the strategy matters (a plain ``least_squares(method="lm")`` stops in a local minimum)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from mbus_framework.pipeline.config import validate_options
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import simulate
from mbus_framework.estimation.problem import FitProblem, FitResult
from mbus_framework.estimation.uncertainty import from_jacobian
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions

TABLE_3_1 = np.array([3.0e8, 15.0, 5.0e7, 12.0])
SET_1 = np.array([2.0, 2.5, 2.0, 2.5])  # dissertation initial set 1 (+100 %, +150 %, ...)


def problem_for(L, D, rho, n, truth, fs, tb, N, noise, seed, **kw):
    model = KelvinVoigtChain(Sample(L, D, rho), KelvinVoigtOptions(n_elements=n))
    w = Prbs(PrbsOptions(order=9, bit_width=tb, sample_rate=fs, n_samples=N)).waveform()
    y0 = simulate(model, truth, w.u, w.dt)
    y = y0 + np.random.default_rng(seed).normal(0.0, noise * np.sqrt(np.mean(y0**2)), N)
    return FitProblem(model, w.t, w.u, y, **kw)


def cost_at(problem: FitProblem, theta) -> float:
    r = problem.y - problem.predict(np.asarray(theta, float))
    return 0.5 * float(r @ r)


def table_like(**kw) -> FitProblem:
    """Table 3.1 material and sampling, 3000 samples instead of 6200."""
    return problem_for(0.05, 0.0254, 1000.0, 10, TABLE_3_1, 6.25e6, 2.5e-6, 3000, 0.10, 1, **kw)


def small_case(**kw) -> FitProblem:
    truth = KelvinVoigtChain(Sample(0.02, 0.0254, 1050.0), KelvinVoigtOptions(n_elements=4)).from_properties(
        {"E_sigma": 3e9, "eta_sigma": 300.0, "E_tau": 5e8, "eta_tau": 400.0}
    )
    return problem_for(0.02, 0.0254, 1050.0, 4, truth, 10e6, 1e-6, 1500, 0.05, 9, **kw), truth


def test_plain_levenberg_marquardt_stops_in_a_local_minimum_the_strategy_does_not():
    """DESIGN.md section 3: from initial set 1 a plain LM fit ends far from the truth, in linear
    parameters (scaled) and in log-parameters alike; the solver with its strategy, from the
    same start, reaches a cost no higher than at the truth."""
    problem = table_like()
    x0 = TABLE_3_1 * SET_1
    c_true = cost_at(problem, TABLE_3_1)

    def residual_linear(theta):
        return problem.predict(theta) - problem.y

    def residual_log(phi):
        return problem.predict(np.exp(phi)) - problem.y

    plain_lin = least_squares(residual_linear, x0, method="lm", x_scale=x0)
    plain_log = least_squares(residual_log, np.log(x0), method="lm")
    for name, res, theta in (("linear", plain_lin, plain_lin.x), ("log", plain_log, np.exp(plain_log.x))):
        assert res.cost > 5 * c_true, f"plain LM ({name}) unexpectedly reached the global minimum"
        assert np.max(np.abs(theta / TABLE_3_1 - 1)) > 0.1, f"plain LM ({name}) ended near the truth"

    problem.initial = x0
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert fit.cost <= c_true * (1 + 1e-6)
    assert fit.strategy["initial_source"] == "config"
    np.testing.assert_allclose(fit.theta, TABLE_3_1, rtol=0.03)


def test_fit_result_contract():
    problem, truth = small_case()
    problem.initial = truth * [3.0, 0.4, 2.0, 0.5]
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert isinstance(fit, FitResult)
    assert fit.names == ["k_sigma", "b_sigma", "k_tau", "b_tau"]
    assert fit.theta.shape == (4,) and np.all(fit.theta > 0)
    assert fit.success is True or fit.success == np.True_
    assert isinstance(fit.status, int) and fit.status > 0
    assert isinstance(fit.message, str) and fit.message
    assert fit.nfev > 0 and fit.njev > 0 and fit.iterations >= 0
    assert fit.wall_time_s > 0
    # cost, residuals and Jacobian are those of the returned theta.
    yhat, J = problem.predict_with_jacobian(fit.theta)
    np.testing.assert_allclose(fit.residuals, problem.y - yhat, rtol=1e-12, atol=1e-15)
    assert fit.cost == pytest.approx(0.5 * float(fit.residuals @ fit.residuals), rel=1e-12)
    assert fit.jacobian.shape == (problem.y.size, 4)
    np.testing.assert_allclose(fit.jacobian, J, rtol=1e-10, atol=1e-12 * np.abs(J).max())
    np.testing.assert_array_equal(fit.free, [True] * 4)
    assert fit.parameters == {n: pytest.approx(v) for n, v in zip(fit.names, fit.theta)}
    # Gradient J^T r vanishes at the minimum (first-order optimality, relative to its scale).
    grad = fit.jacobian.T @ fit.residuals
    scale = np.linalg.norm(fit.jacobian, axis=0) * np.linalg.norm(fit.residuals)
    assert np.all(np.abs(grad) <= 1e-4 * scale), grad / scale
    # What the strategy did is reported.
    assert fit.strategy["starts"] and fit.strategy["winner"] is not None
    assert fit.extras["method"] == "lm"
    assert fit.trace and {"iteration", "cost", "theta"} <= set(fit.trace[0])


def test_jacobian_agrees_with_central_differences():
    problem, truth = small_case()
    _, J = problem.predict_with_jacobian(truth)
    for i in range(4):
        h = 1e-6 * truth[i]
        up, dn = truth.copy(), truth.copy()
        up[i] += h
        dn[i] -= h
        fd = (problem.predict(up) - problem.predict(dn)) / (2 * h)
        np.testing.assert_allclose(J[:, i], fd, rtol=0, atol=1e-5 * np.abs(fd).max())


def test_fixed_parameter_is_held_exactly():
    problem, truth = small_case(fixed={})
    fixed = {"b_tau": float(truth[3])}
    problem = FitProblem(problem.model, problem.t, problem.u, problem.y, initial=truth * [2.0, 2.0, 0.5, 1.0], fixed=fixed)
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert fit.theta[3] == truth[3]
    np.testing.assert_array_equal(fit.free, [True, True, True, False])
    assert fit.jacobian.shape == (problem.y.size, 3)
    assert fit.cost <= cost_at(problem, truth) * (1 + 1e-6)
    unc = from_jacobian(["k_sigma", "b_sigma", "k_tau"], fit.jacobian, fit.cost)
    assert np.all(np.abs(fit.theta[:3] - truth[:3]) < 4 * unc.standard_errors)


def test_finite_difference_jacobian_finds_the_same_minimum():
    problem, truth = small_case()
    problem.initial = truth * [1.5, 0.7, 1.3, 0.8]
    exact = ScipyLM(ScipyLMOptions()).solve(problem)
    fd = ScipyLM(ScipyLMOptions(jacobian="finite_difference")).solve(problem)
    np.testing.assert_allclose(fd.theta, exact.theta, rtol=1e-4)
    assert fd.cost == pytest.approx(exact.cost, rel=1e-6)
    assert fd.extras["jacobian"] == "finite_difference"


def test_noise_free_data_are_fitted_exactly():
    """(Three starts: on noise-free data the default search never stops early, see
    test_strategy.py.)"""
    problem, truth = small_case()
    clean = FitProblem(problem.model, problem.t, problem.u, simulate(problem.model, truth, problem.u, problem.dt),
                       initial=truth * [0.5, 2.0, 2.0, 0.5])
    options = validate_options(ScipyLMOptions, {"strategy": {"n_starts": 3}}, "solver.options")
    fit = ScipyLM(options).solve(clean)
    np.testing.assert_allclose(fit.theta, truth, rtol=1e-6)
    assert fit.cost < 1e-12 * 0.5 * float(clean.y @ clean.y)


def test_registered_and_options_validated():
    reg = Registry.from_manager(new_plugin_manager())
    spec = reg.get("solver", "scipy_lm")
    assert spec.implementation is ScipyLM
    opts = validate_options(ScipyLM.Options, {"strategy": {"n_starts": 3}, "xtol": 1e-8}, "solver.options")
    assert opts.strategy.n_starts == 3 and opts.xtol == 1e-8
    solver = spec.implementation(opts)
    assert solver.options is opts
