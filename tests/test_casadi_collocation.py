"""``casadi_collocation``: discretisation accuracy, formulations, truth recovery, bounds,
nuisance parameters, unsupported inputs, console output and the common result fields."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import ValidationError

from mbus_framework.errors import EstimationError
from mbus_framework.estimation.nuisance import NuisanceSettings, delayed_prediction
from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import discretize, simulate
from mbus_framework.estimation.problem import FitProblem
from mbus_framework.pipeline.storage import to_jsonable
from mbus_framework.estimation.strategy import BandFilter
from mbus_framework.testing.solvers import contract_problem
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.solvers.casadi_collocation import (
    CasadiCollocation,
    CasadiCollocationOptions,
    butterworth_ss,
    filter_data,
    stability_polynomials,
    transition_function,
)
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions

TABLE_3_1 = np.array([3.0e8, 15.0, 5.0e7, 12.0])
SET_1 = np.array([2.0, 2.5, 2.0, 2.5])  # dissertation initial set 1 (+100 %, +150 %, ...)
LOCAL = {"global_search": False}


def table_like(n_samples=1500, noise=0.10, seed=1, n=10, **kw):
    model = KelvinVoigtChain(Sample(0.05, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=n))
    w = Prbs(PrbsOptions(order=9, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=n_samples)).waveform()
    y0 = simulate(model, TABLE_3_1, w.u, w.dt)
    y = y0 + np.random.default_rng(seed).normal(0.0, noise * np.sqrt(np.mean(y0**2)), n_samples)
    return FitProblem(model, w.t, w.u, y, **kw)


def solve(problem, **options):
    return CasadiCollocation(CasadiCollocationOptions(**options)).solve(problem)


def collocation_output(model, theta, u, dt, scheme, degree, hold="zoh"):
    """Simulate the collocation recursion (unit scales) for comparison with the exact ZOH."""
    n = discretize(model.state_space(theta), dt).Phi.shape[0]
    # balance with the exact state magnitudes, as the solver does
    d = discretize(model.state_space(theta), dt, hold)
    x, peak = np.zeros(n), np.zeros(n)
    for k in range(u.size - 1):
        x = d.Phi @ x + d.Gamma * u[k]
        peak = np.maximum(peak, np.abs(x))
    f = transition_function(model, len(theta), dt, degree, scheme, hold)
    Phi, Gam, C, D = (np.array(v, dtype=float) for v in f(theta, peak, 1.0))
    Gam = Gam.reshape(n, -1)
    x, y = np.zeros(n), np.zeros(u.size)
    un = np.append(u[1:], u[-1])
    for k in range(u.size):
        y[k] = C.ravel() @ x + D.item() * u[k]
        v = np.array([u[k]]) if hold == "zoh" else np.array([u[k], un[k]])
        x = Phi @ x + Gam @ v
    return y


# -- discretisation ---------------------------------------------------------------------------
def test_stability_functions_are_the_known_pade_approximants():
    p, q = stability_polynomials(2, "legendre")  # (2,2) Pade: 1 +- z/2 + z^2/12
    np.testing.assert_allclose(p, [1, 0.5, 1 / 12], atol=1e-14)
    np.testing.assert_allclose(q, [1, -0.5, 1 / 12], atol=1e-14)
    p, q = stability_polynomials(2, "radau")  # (1,2) Pade: (1 + z/3) / (1 - 2z/3 + z^2/6)
    np.testing.assert_allclose(p, [1, 1 / 3, 0], atol=1e-14)
    np.testing.assert_allclose(q, [1, -2 / 3, 1 / 6], atol=1e-14)
    for d in (1, 3, 4):  # R(z) - e^z = O(z^(2d+1)) for Gauss-Legendre
        p, q = stability_polynomials(d, "legendre")
        z = 0.05
        R = np.polyval(p[::-1], z) / np.polyval(q[::-1], z)
        assert abs(R - np.exp(z)) < z ** (2 * d + 1) / math.factorial(2 * d)


@pytest.mark.parametrize("scheme, degree, tol", [("legendre", 3, 1e-8), ("radau", 3, 1e-6), ("legendre", 2, 1e-4)])
def test_collocation_reproduces_the_exact_zoh_simulation(scheme, degree, tol):
    problem = table_like(n_samples=3000, noise=0.0)
    y_exact = simulate(problem.model, TABLE_3_1, problem.u, problem.dt)
    y_coll = collocation_output(problem.model, TABLE_3_1, problem.u, problem.dt, scheme, degree)
    assert np.linalg.norm(y_coll - y_exact) / np.linalg.norm(y_exact) < tol


def test_collocation_order_of_accuracy():
    """Halving h divides the error of Legendre d=2 by ~2^4 and of the trapezoidal rule by ~2^2."""
    model = KelvinVoigtChain(Sample(0.02, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=3))
    theta = model.from_properties({"E_sigma": 2.5e9, "eta_sigma": 150.0, "E_tau": 6e8, "eta_tau": 150.0})
    lam = np.max(np.abs(np.linalg.eigvals(np.asarray(model.state_space(theta).A, float))))
    T = 400 * 0.2 / lam
    for scheme, degree, order in (("legendre", 2, 4), ("trapezoidal", 1, 2)):
        errs = []
        for steps in (400, 800):
            dt = T / steps
            u = np.repeat(np.random.default_rng(0).choice([-1.0, 1.0], 50), steps // 50)
            y = simulate(model, theta, u, dt)
            errs.append(np.linalg.norm(collocation_output(model, theta, u, dt, scheme, degree) - y) / np.linalg.norm(y))
        assert errs[0] / errs[1] == pytest.approx(2.0**order, rel=0.25), (scheme, errs)


def test_first_order_hold_matches_the_exact_foh_simulation():
    problem = table_like(n_samples=2000, noise=0.0)
    y_exact = simulate(problem.model, TABLE_3_1, problem.u, problem.dt, "foh")
    y_coll = collocation_output(problem.model, TABLE_3_1, problem.u, problem.dt, "legendre", 3, "foh")
    assert np.linalg.norm(y_coll - y_exact) / np.linalg.norm(y_exact) < 1e-8


def test_band_filter_is_the_strategy_filter_made_causal():
    """Same |H| as the strategy's zero-phase filter (to the bilinear warping), same output as
    scipy's sosfilt."""
    from scipy import signal

    dt, fc = 1 / 6.25e6, 40e3
    A, B, C, D = butterworth_ss(fc, dt)
    f = np.array([5e3, 20e3, 40e3, 80e3, 160e3])
    z = np.exp(2j * np.pi * f * dt)
    H = np.array([C @ np.linalg.solve(zk * np.eye(4) - A, B) + D for zk in z])
    np.testing.assert_allclose(np.abs(H), 1 / np.sqrt(1 + (f / fc) ** 8), rtol=1e-2)
    x = np.random.default_rng(1).standard_normal(2000)
    sos = signal.butter(4, fc / (0.5 / dt), output="sos")
    np.testing.assert_allclose(filter_data(A, B, C, D, x), signal.sosfilt(sos, x), atol=1e-12)
    # the energy of a low-passed residual is the zero-phase one (Parseval), end effects aside
    zp = BandFilter(fc, x.size, dt)
    assert np.linalg.norm(filter_data(A, B, C, D, x)) == pytest.approx(np.linalg.norm(zp(x)), rel=0.05)


# -- formulations -----------------------------------------------------------------------------
def test_formulations_and_node_spacing_give_the_same_optimum():
    """Exact elimination: condensed (any samples_per_node) and full collocation agree."""
    problem, truth = contract_problem(n_samples=300, n_elements=2)
    problem.y = problem.y + np.random.default_rng(2).normal(0, 0.05 * np.std(problem.y), problem.y.size)
    problem.initial = truth * 1.1
    fits = {key: solve(problem, **LOCAL, **opts) for key, opts in {
        "auto": {}, "m=1": {"samples_per_node": 1}, "m=7": {"samples_per_node": 7},
        "full": {"formulation": "full"}, "exact hessian": {"hessian": "exact"}}.items()}
    ref = fits["auto"].theta
    for key, fit in fits.items():
        assert fit.success, (key, fit.message)
        np.testing.assert_allclose(fit.theta, ref, rtol=1e-7, err_msg=key)
    assert fits["m=1"].extras["nlp_size"]["state_nodes"] == 300
    assert fits["m=7"].extras["nlp_size"]["state_nodes"] == 43
    n, N, d = 4, 300, 3  # full: parameters, sample states, d collocation-point states per interval
    assert fits["full"].extras["nlp_size"]["variables"] == 4 + n * N + n * d * (N - 1)


def test_trapezoidal_rule_is_biased_by_its_frequency_warping():
    problem, truth = contract_problem(n_samples=600)
    problem.initial = truth * 1.05
    fit = solve(problem, scheme="trapezoidal", **LOCAL)
    assert fit.success
    bias = np.abs(fit.theta / truth - 1)
    assert 1e-4 < bias.max() < 0.05  # (w h)^2 / 12 with |lambda| h = 0.12: a per-cent level bias
    assert 1e-4 < fit.extras["discretisation_error"] < 0.05


# -- estimation -------------------------------------------------------------------------------
def test_recovers_table_3_1_from_initial_set_1_like_scipy():
    """Global search + collocation from +100/+150 % (1500 samples, 10 % noise)."""
    problem = table_like(initial=TABLE_3_1 * SET_1)
    fit = solve(problem)
    ref = ScipyLM(ScipyLMOptions()).solve(problem)
    assert fit.success, fit.message
    np.testing.assert_allclose(fit.theta, ref.theta, rtol=1e-6)
    r_true = problem.y - problem.predict(TABLE_3_1)
    assert fit.cost <= 0.5 * float(r_true @ r_true)
    assert fit.extras["discretisation_error"] < 1e-8
    assert fit.strategy["initial_source"] == "config"


def test_local_solve_from_a_start_near_the_truth():
    problem = table_like(n_samples=1500, noise=0.0, initial=TABLE_3_1 * [1.1, 0.8, 0.9, 1.25])
    fit = solve(problem, **LOCAL)
    np.testing.assert_allclose(fit.theta, TABLE_3_1, rtol=1e-7)
    assert fit.strategy == {"initial_source": "config", "initial": dict(zip(problem.names, TABLE_3_1 * [1.1, 0.8, 0.9, 1.25])),
                            "global_search": False}
    assert fit.iterations == fit.extras["ipopt"]["iter_count"] > 0


def test_no_initial_values_start_from_the_model_guess():
    problem, truth = contract_problem(n_samples=600)
    fit = solve(problem, strategy={"n_starts": 2})
    assert fit.strategy["initial_source"] == "model.initial_guess"
    np.testing.assert_allclose(fit.theta, truth, rtol=1e-6)


def test_bounds_are_respected_exactly():
    problem, truth = contract_problem(n_samples=400)
    upper = problem.upper.copy()
    upper[2] = 0.8 * truth[2]
    problem.upper, problem.initial = upper, truth * 0.7
    fit = solve(problem, **LOCAL)
    assert np.all(fit.theta <= problem.upper) and np.all(fit.theta >= problem.lower)
    assert fit.theta[2] == pytest.approx(upper[2], rel=1e-6)


def test_input_gain_estimated_and_fixed_delay():
    problem, truth = contract_problem(n_samples=500)
    dt = problem.dt
    for delay in (0.0, 2.4 * dt, 3 * dt):
        y = delayed_prediction(problem.model, truth, problem.u, dt, 2.5, delay)
        p = FitProblem(problem.model, problem.t, problem.u, y, initial=np.r_[truth * 1.05, 2.0, delay],
                       nuisance=NuisanceSettings(estimate_gain=True, delay=delay))
        fit = solve(p, **LOCAL)
        np.testing.assert_allclose(fit.theta, np.r_[truth, 2.5, delay], rtol=1e-7, atol=1e-15)
        assert fit.extras["discretisation_error"] < 1e-8


def test_unsupported_problems_are_reported():
    problem, truth = contract_problem(n_samples=200)
    p = FitProblem(problem.model, problem.t, problem.u, problem.y, initial=np.r_[truth, 1.0, 0.0],
                   nuisance=NuisanceSettings(estimate_delay=True))
    with pytest.raises(EstimationError, match="delay"):
        solve(p)
    p = FitProblem(problem.model, problem.t, problem.u, problem.y, output_filter=lambda x, dt: x)
    with pytest.raises(EstimationError, match="output filter"):
        solve(p)


def test_options_are_validated():
    with pytest.raises(ValidationError):
        CasadiCollocationOptions(scheme="lobatto")
    with pytest.raises(ValidationError):
        CasadiCollocationOptions(samples_per_node=0)
    with pytest.raises(ValidationError):
        CasadiCollocationOptions(ipopt_options={})
    assert CasadiCollocationOptions(ipopt={"mu_strategy": "adaptive"}).ipopt == {"mu_strategy": "adaptive"}


def test_ipopt_options_reach_ipopt():
    problem, truth = contract_problem(n_samples=300)
    problem.initial = truth * 1.3
    fit = solve(problem, **LOCAL, ipopt={"max_iter": 2})
    assert fit.extras["ipopt"]["return_status"] == "Maximum_Iterations_Exceeded"
    assert not fit.success and fit.status == 0 and fit.iterations == 2


def test_ipopt_output_only_when_asked_or_interactive(capfd):
    problem, truth = contract_problem(n_samples=200)
    problem.initial = truth * 1.1
    solve(problem, **LOCAL)  # pytest's stdout is not a terminal: quiet
    assert "iter" not in capfd.readouterr().out
    solve(problem, **LOCAL, print_level=5)
    out = capfd.readouterr().out
    assert "objective" in out and "inf_pr" in out


def test_result_fields_and_extras():
    problem, truth = contract_problem(n_samples=400)
    problem.y = problem.y + np.random.default_rng(0).normal(0, 0.05 * np.std(problem.y), problem.y.size)
    problem.initial = truth * 1.2
    fit = solve(problem, **LOCAL)
    ex = fit.extras
    assert ex["method"] == "ipopt" and ex["scheme"] == "legendre" and ex["degree"] == 3
    # IPOPT's own tolerance, or the xtol/ftol test of the iteration callback
    assert fit.success and ex["ipopt"]["return_status"] in ("Solve_Succeeded", "User_Requested_Stop")
    assert fit.status == (1 if ex["ipopt"]["return_status"] == "Solve_Succeeded" else 4)
    size = ex["nlp_size"]
    assert size["variables"] == size["free_parameters"] + size["states"] * size["state_nodes"]
    assert size["constraints"] == size["states"] * (size["state_nodes"] - 1)
    assert ex["collocation_cost"] == pytest.approx(fit.cost, rel=1e-8)
    assert len(fit.trace) == fit.iterations + 1 and fit.trace[-1]["theta"] == pytest.approx(list(fit.theta))
    json.dumps(to_jsonable(ex))
    # uncertainty: the Jacobian is the exact model's sensitivity at the estimate
    _, J = problem.predict_with_jacobian(fit.theta)
    np.testing.assert_allclose(fit.jacobian, J, rtol=1e-12)


@pytest.mark.slow
def test_table_3_1_full_record_from_all_three_starts():
    """The benchmark case: 6200 samples, 10 % noise, three starts, against scipy_lm."""
    problem = table_like(n_samples=6200)
    ref = ScipyLM(ScipyLMOptions()).solve(problem)
    for factors in (SET_1, [0.65, 0.5, 0.65, 0.5], [0.1, 10, 10, 0.1]):
        problem.initial = TABLE_3_1 * np.asarray(factors)
        fit = solve(problem)
        np.testing.assert_allclose(fit.theta, ref.theta, rtol=1e-3)
        assert fit.wall_time_s < 120
