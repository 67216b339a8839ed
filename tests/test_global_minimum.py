"""The estimator on the dissertation's materials, from the default start and from far starts.

Records come from an independent simulator (scipy's exact ZOH discretisation and ``dlsim``),
the PRBS sequences from scipy's ``max_len_seq`` with other taps and seeds than the shipped
excitation's, and success is judged against the Cramer-Rao standard errors at the truth:
every parameter within max(4 CRB SE, 0.5 %) of the truth (the benchmark's criterion).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import signal
from scipy.signal import max_len_seq

from mbus_framework.engine.simulation import simulate_with_sensitivities
from mbus_framework.estimation.problem import FitProblem
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions

#: Tables 4.2 and 4.3: density [kg/m^3], E_sigma [Pa], eta_sigma [Pa s], E_tau [Pa], eta_tau [Pa s]
CHAPTER4 = {
    "water": (998, 3.22e12, 3.07e5, 2.11e12, 5.18e5),
    "milk": (1006, 3.39e12, 3.96e5, 2.31e12, 5.55e5),
    "syrup-1": (1093, 3.97e12, 4.88e5, 2.59e12, 6.18e5),
    "syrup-2": (1197, 4.60e12, 7.24e5, 3.11e12, 6.83e5),
    "syrup-3": (1307, 4.53e12, 4.99e5, 3.11e12, 7.21e5),
    "muscle-0": (1070, 2.82e12, 4.94e5, 2.62e12, 6.14e5),
    "muscle-90": (1070, 2.92e12, 5.26e5, 2.69e12, 5.84e5),
    "liver": (1060, 1.37e12, 3.96e5, 3.05e12, 4.56e5),
    "kidney": (1040, 1.97e12, 1.92e5, 2.78e12, 5.36e5),
    "fat": (919.6, 2.80e12, 2.75e5, 2.03e12, 5.41e5),
}


def record(model, theta, order, bit, fs, n, noise, seed, taps=None, state=None):
    """(problem, noise std): a PRBS record simulated by scipy, Gaussian noise of ``noise`` x RMS."""
    st = None if state is None else np.array([(state >> i) & 1 for i in range(order)], dtype=np.int8)
    seq = max_len_seq(order, state=st, taps=taps)[0] * 2.0 - 1.0
    t = np.arange(n) / fs
    u = seq[np.floor(t / bit + 1e-9).astype(int) % seq.size]
    A, B, C, D = (np.asarray(m, float) for m in model.state_space(theta))
    sysd = signal.cont2discrete((A, B, C, D), 1 / fs, method="zoh")
    _, y0, _ = signal.dlsim((*sysd[:4], 1 / fs), u)
    y0 = y0.ravel()
    sigma = noise * np.sqrt(np.mean(y0**2))
    y = y0 + np.random.default_rng(seed).normal(0, sigma, n)
    return FitProblem(model=model, t=t, u=u, y=y), sigma


def crb(problem, theta, sigma):
    """Relative Cramer-Rao standard errors at the truth (known noise)."""
    _, J = simulate_with_sensitivities(problem.model, theta, problem.u, problem.dt)
    cov = sigma**2 * np.linalg.inv((J * theta).T @ (J * theta))
    return np.sqrt(np.diag(cov))


def assert_recovered(fit, theta, rel_crb, label):
    err = np.abs(fit.theta / theta - 1)
    ok = err <= np.maximum(4 * rel_crb, 0.005)
    assert ok.all(), f"{label}: |error| {np.round(100 * err, 3)} % vs 4 CRB {np.round(400 * rel_crb, 3)} %"
    assert fit.strategy["accepted"], f"{label}: {fit.strategy['accepted_because']}"


def chapter4(name, L=0.05, n=10):
    rho, Es, es, Et, et = CHAPTER4[name]
    model = KelvinVoigtChain(Sample(L, 0.0254, rho), KelvinVoigtOptions(n_elements=n))
    theta = np.asarray(model.from_properties(dict(E_sigma=Es, eta_sigma=es, E_tau=Et, eta_tau=et)))
    return model, theta


@pytest.mark.parametrize("name", ["water", "liver"])
def test_liquids_and_tissues_from_the_default_start(name):
    """Chapter 4 media: stiff and near critical damping, the response within ~1 us; no
    first arrival to pick. PRBS 0.4 us at 25 MS/s, 6200 samples, 5 % noise (issue 11)."""
    model, theta = chapter4(name)
    problem, sigma = record(model, theta, 9, 0.4e-6, 25e6, 6200, 0.05, seed=1, state=300)
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert_recovered(fit, theta, crb(problem, theta, sigma), name)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CHAPTER4))
@pytest.mark.parametrize("setting", [(0.4e-6, 25e6), (2.5e-6, 6.25e6)])
def test_every_chapter4_material_from_the_default_start(name, setting):
    model, theta = chapter4(name)
    problem, sigma = record(model, theta, 10, setting[0], setting[1], 6200, 0.05, seed=7, state=99)
    rel = crb(problem, theta, sigma)
    if rel.max() > 0.2:
        pytest.skip("practically unidentifiable with this record (largest CRB > 20 %)")
    assert_recovered(ScipyLM(ScipyLMOptions()).solve(problem), theta, rel, f"{name} {setting}")


@pytest.mark.parametrize("noise", [0.02, 0.10, 0.20])
def test_table_3_1_with_another_prbs_sequence(noise):
    """Table 3.1 from (x0.2, x5, x5, x0.2) with a maximal-length PRBS of other taps and seed
    than the shipped one (same bit width and sample rate): issue 11, item 3."""
    model = KelvinVoigtChain(Sample(0.05, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=10))
    theta = np.array([3e8, 15.0, 5e7, 12.0])
    problem, sigma = record(model, theta, 9, 2.5e-6, 6.25e6, 6200, noise, seed=int(100 * noise),
                            taps=[7, 6, 4], state=0b101100111)  # x^9 + x^7 + x^6 + x^4 + 1 (maximal)
    problem.initial = theta * np.array([0.2, 5.0, 5.0, 0.2])
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert_recovered(fit, theta, crb(problem, theta, sigma), f"Table 3.1 at {noise:.0%} noise")


def test_stiff_undamped_start_does_not_run_off_on_a_heavily_damped_liquid():
    """Issue 11, item 4: from (x5, x0.2, x0.2, x5) k used to run to ~200x the truth."""
    model, theta = chapter4("syrup-2")
    problem, sigma = record(model, theta, 9, 0.4e-6, 25e6, 6200, 0.05, seed=4)
    problem.initial = theta * np.array([5.0, 0.2, 0.2, 5.0])
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert_recovered(fit, theta, crb(problem, theta, sigma), "syrup-2 from a stiff, undamped start")


def test_the_periodic_record_of_a_short_prbs():
    """A PRBS of 127 bits repeats five times in the record: the search works on its lines."""
    model = KelvinVoigtChain(Sample(0.03, 0.0254, 1080.0), KelvinVoigtOptions(n_elements=10))
    theta = np.asarray(model.from_properties(dict(E_sigma=2.42e10, eta_sigma=7.18e3, E_tau=6.56e9, eta_tau=5.14e3)))
    problem, sigma = record(model, theta, 7, 0.4e-6, 25e6, 6200, 0.15, seed=12, state=26)
    fit = ScipyLM(ScipyLMOptions()).solve(problem)
    assert_recovered(fit, theta, crb(problem, theta, sigma), "potato, periodic PRBS")
    assert fit.strategy["noise"]["periods_std"] == pytest.approx(sigma, rel=0.1)
