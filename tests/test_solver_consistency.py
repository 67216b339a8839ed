"""Property tests: the two independent estimators agree.

``scipy_lm`` fits the output error by single shooting with the exact ZOH simulator;
``casadi_collocation`` fits the same cost with the states as NLP variables and the model
equations (collocation, Gauss-Legendre d = 3) as constraints. For random Kelvin-Voigt media
(properties log-uniform in physical ranges, 2-5 elements, random PRBS-like input, start
within x/÷ 1.3 of the truth):

* noise-free data: both recover the truth and agree to 1e-4 relative;
* noisy data (5 %): both reach the same minimum, |theta_casadi - theta_scipy| <= 0.1 SE
  (SE the linearised standard error of :mod:`mbus_framework.estimation.uncertainty`).

The default run draws a few examples with one start of the global strategy (deterministic
under HYPOTHESIS_PROFILE=ci); the ``slow`` variants run the solvers as shipped (full strategy)
on longer records with up to 10 elements.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import simulate
from mbus_framework.estimation.problem import FitProblem
from mbus_framework.estimation.uncertainty import from_jacobian
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.solvers.casadi_collocation import CasadiCollocation, CasadiCollocationOptions
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions

# Physical ranges (Table 3.1 is E_sigma 3.0 GPa, eta_sigma 148 Pa s, E_tau 0.63 GPa, eta_tau 150 Pa s)
RANGES = {"E_sigma": (1.5e9, 4.0e9), "eta_sigma": (60.0, 400.0), "E_tau": (2.0e8, 1.0e9), "eta_tau": (60.0, 400.0)}
FS, BIT = 6.25e6, 2.5e-6  # Fig. 3.7 setting 1
ONE_START = {"n_starts": 1}  # the default run: one start of the global strategy per solver


@st.composite
def media(draw, max_elements: int = 5):
    props = {k: float(np.exp(draw(st.floats(np.log(lo), np.log(hi)), label=k))) for k, (lo, hi) in RANGES.items()}
    n = draw(st.integers(2, max_elements), label="n_elements")
    length = draw(st.sampled_from([0.01, 0.02, 0.03]), label="length")
    factors = np.exp(np.array(draw(st.lists(st.floats(-np.log(1.3), np.log(1.3)), min_size=4, max_size=4),
                                   label="start log-factors")))
    seed = draw(st.integers(0, 2**16), label="seed")
    return props, n, length, factors, seed


def make_problem(props, n, length, factors, seed, n_samples, noise):
    model = KelvinVoigtChain(Sample(length, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=n))
    truth = model.from_properties(props)
    w = Prbs(PrbsOptions(order=9, bit_width=BIT, sample_rate=FS, n_samples=n_samples, shift=seed % 511)).waveform()
    y = simulate(model, truth, w.u, w.dt)
    if noise:
        y = y + np.random.default_rng(seed).normal(0.0, noise * np.sqrt(np.mean(y**2)), y.size)
    return FitProblem(model, w.t, w.u, y, initial=truth * factors), truth


def both(problem, strategy):
    fs = ScipyLM(ScipyLMOptions(strategy=strategy)).solve(problem)
    fc = CasadiCollocation(CasadiCollocationOptions(strategy=strategy)).solve(problem)
    return fs, fc


def check_noise_free(case, n_samples, strategy):
    problem, truth = make_problem(*case, n_samples=n_samples, noise=0.0)
    fs, fc = both(problem, strategy)
    for name, fit in (("scipy_lm", fs), ("casadi_collocation", fc)):
        err = np.abs(fit.theta / truth - 1)
        assert np.all(err < 1e-5), f"{name} missed the truth: relative errors {err}; {fit.message}"
    rel = np.abs(fc.theta / fs.theta - 1)
    assert np.all(rel < 1e-4), f"solvers disagree by {rel}"


def check_noisy(case, n_samples, strategy, noise=0.05, fraction=0.1):
    problem, truth = make_problem(*case, n_samples=n_samples, noise=noise)
    fs, fc = both(problem, strategy)
    se = from_jacobian(problem.names, fs.jacobian, fs.cost).standard_errors
    diff = np.abs(fc.theta - fs.theta)
    assert np.all(diff <= fraction * se), (
        f"solvers differ by {diff / se} standard errors (SE {se}); costs {fs.cost:.9g} {fc.cost:.9g}")
    np.testing.assert_allclose(fc.cost, fs.cost, rtol=1e-6)
    # and the common minimum is where the truth lies (within 5 SE)
    assert np.all(np.abs(fs.theta - truth) <= 5 * se), f"estimate {fs.theta} vs truth {truth}, SE {se}"


@settings(max_examples=5)
@given(case=media())
def test_noise_free_both_recover_truth_and_agree(case):
    check_noise_free(case, n_samples=1000, strategy=ONE_START)


@settings(max_examples=5)
@given(case=media())
def test_noisy_estimates_agree_within_a_fraction_of_the_standard_error(case):
    check_noisy(case, n_samples=1000, strategy=ONE_START)


# The slow variants run both solvers as shipped (default strategy: on noise-free data no start
# has white residuals, so all 12 starts run). With one start, scipy_lm started at the truth of
# ({E_sigma: 3.585e9, eta_sigma: 148.4, E_tau: 9.064e8, eta_tau: 148.4}, n=6, L=0.03) ends at
# k_sigma x 407: the time-scale alignment moves that start to c = 0.59.
@pytest.mark.slow
@settings(max_examples=6)
@given(case=media(max_elements=10))
def test_noise_free_agreement_many_cases(case):
    check_noise_free(case, n_samples=2500, strategy={})


@pytest.mark.slow
@settings(max_examples=6)
@given(case=media(max_elements=10))
def test_noisy_agreement_many_cases(case):
    check_noisy(case, n_samples=2500, strategy={}, noise=0.10)
