"""Routing of the search (:mod:`mbus_framework.estimation.routing`): a record no time-domain
start explains and whose identified poles ring goes to the pole starts before the scan.

References: damping ratios of poles built from known continuous-time eigenvalues
(s = -ζω ± iω√(1-ζ²), z = e^{sΔt}); a nearly undamped chain simulated by scipy's exact ZOH
discretisation (tests/test_record_poles.py); the same record at 300 % noise (noise-dominated:
routing must not change the order there).
"""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.estimation.routing import all_null, least_damping, noise_dominated, null_cost, record_damping
from mbus_framework.estimation.strategy import StrategyOptions
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions
from tests.test_global_minimum import assert_recovered, crb, record
from tests.test_record_poles import ringing_chain


@pytest.mark.parametrize("zeta", [1e-4, 3e-3, 0.05, 0.4])
def test_least_damping_recovers_the_damping_ratio_of_discrete_poles(zeta):
    dt, omegas = 1e-7, np.array([2e6, 9e6, 4e7])  # the last one aliases (above Nyquist 3.1e7 rad/s)
    zetas = np.array([zeta, 2 * zeta, 0.9])
    s = -zetas * omegas + 1j * omegas * np.sqrt(1 - zetas**2)
    z = np.exp(np.concatenate([s, s.conj()]) * dt)
    z = np.append(z, 0.5)  # a real pole does not oscillate: ignored
    assert least_damping(z, dt) == pytest.approx(zeta, rel=1e-6, abs=1e-9)


def test_least_damping_without_oscillating_or_stable_poles_is_infinite():
    assert least_damping(np.array([0.3, 0.9]), 1e-6) == np.inf
    assert least_damping(np.array([1.2 + 0.1j, 1.2 - 0.1j]), 1e-6) == np.inf
    assert least_damping(np.empty(0, complex), 1e-6) == np.inf


def test_null_and_noise_dominated():
    y = np.array([3.0, -4.0])
    assert null_cost(y) == 12.5
    assert all_null([12.5, 12.0], 12.5, 0.05) and not all_null([12.5, 11.0], 12.5, 0.05)
    assert not all_null([], 12.5, 0.05)
    assert noise_dominated(12.5, 2, 7.0) and not noise_dominated(12.5, 2, 6.0)
    assert not noise_dominated(12.5, 2, None)


def slice_record(noise):
    """The stiff, nearly undamped 2.5 cm slice at 0.4 us / 25 MS/s of test_record_poles."""
    model, theta = ringing_chain(8e11, 40.0, 1.2e12, 20.0, L=0.025, rho=1200.0, D=0.01905)
    problem, sigma = record(model, theta, 11, 0.4e-6, 25e6, 6200, noise, seed=11, taps=[9, 8, 6], state=779)
    return model, theta, problem, sigma


def test_a_ringing_record_no_start_explains_goes_to_the_pole_starts_before_the_scan():
    model, theta, problem, sigma = slice_record(0.04)
    exact = np.exp(np.linalg.eigvals(np.asarray(model.state_space(theta)[0], float)) * problem.dt)
    assert least_damping(exact, problem.dt) < 1e-3  # the chain rings, and so do its identified poles
    assert record_damping(problem) < StrategyOptions().light_damping
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert_recovered(fit, theta, crb(problem, theta, sigma), "ringing slice")
    st = fit.strategy
    assert st["starts"][st["winner"]]["origin"] == "record poles"
    assert st["scan"] is None  # accepted before the scan was needed
    routing = st["poles"]["routing"]
    assert routing["before_scan"] and routing["null_cost"] == pytest.approx(null_cost(problem.y))
    before = [s for s in st["starts"] if s["origin"] != "record poles"]
    assert before and all(s["cost"] >= 0.95 * routing["null_cost"] for s in before)


def test_the_rule_switched_off_scans_first():
    _, theta, problem, sigma = slice_record(0.04)
    fit = ScipyLM(ScipyLMOptions(strategy=StrategyOptions(poles_first=False))).solve(problem)
    assert fit.strategy["scan"] is not None
    assert "routing" not in (fit.strategy["poles"] or {})


def test_a_noise_dominated_ringing_record_keeps_the_usual_order():
    """At 300 % noise every end explains little of the record by nature: no routing."""
    _, theta, problem, sigma = slice_record(3.0)
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert "routing" not in (fit.strategy["poles"] or {})
    origins = [s["origin"] for s in fit.strategy["starts"]]
    if "record poles" in origins:  # the pole starts come after the scan's starts, as before
        assert fit.strategy["scan"] is not None
