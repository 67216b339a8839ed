"""How far the estimates can be trusted: the frequency-domain solver against the time-domain
fit, profile-likelihood intervals against the linearised ones, and the information gate.

Records come from scipy's exact ZOH discretisation (``tests/test_global_minimum.record``) of
the Kelvin-Voigt chain with potato-like properties (Table 3.1) and white Gaussian noise.
"""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.api import fit
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.solvers.frequency_domain import FrequencyDomain, FrequencyDomainOptions
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions
from tests.test_global_minimum import record

POTATO = {"E_sigma": 2.5e6, "eta_sigma": 150.0, "E_tau": 6.0e5, "eta_tau": 150.0}
GEOMETRY = {"length": 0.01, "diameter": 0.0254, "density": 1080.0}


def potato(n_elements=3):
    model = KelvinVoigtChain(Sample(**GEOMETRY), KelvinVoigtOptions(n_elements=n_elements))
    return model, np.asarray(model.from_properties(POTATO))


def standard_errors(result) -> np.ndarray:
    """Linearised SEs sqrt(diag(s^2 (J^T J)^-1)), s^2 = 2 cost / (N - p), free parameters."""
    J = result.jacobian
    s2 = 2 * result.cost / (result.residuals.size - J.shape[1])
    return np.sqrt(np.diag(s2 * np.linalg.inv(J.T @ J)))


@pytest.mark.parametrize("seed", [1, 2])
def test_frequency_domain_agrees_with_the_time_domain_fit_on_a_periodic_record(seed):
    """Pure frequency-domain estimate (no time-domain polish) within 0.75 SE of scipy_lm's.

    The frequency-domain fit drops the first of the 10 periods (its transient), so the two
    estimates differ by about sqrt(10/9 - 1) = 0.33 SE from the data alone."""
    model, truth = potato()
    # PRBS order 9, 4 samples per bit at 1.6 MS/s: 2044 samples per period, 8.4 times the
    # slowest decay time; 10 periods, 3 % noise
    problem, _ = record(model, truth, order=9, bit=2.5e-6, fs=1.6e6, n=2044 * 10, noise=0.03, seed=seed,
                        taps=[8, 6, 5] if seed == 2 else None)
    problem.initial = truth * np.array([1.3, 0.7, 0.8, 1.25])
    td = ScipyLM(ScipyLMOptions()).solve(problem)
    fd = FrequencyDomain(FrequencyDomainOptions(polish=False)).solve(problem)
    assert fd.extras["period_samples"] == 2044 and not fd.extras["polished"]
    se = standard_errors(td)
    gap = np.abs(fd.theta - td.theta) / se
    assert np.all(gap < 0.75), f"|FD - TD| / SE = {np.round(gap, 3)}"
    # both near the truth: the comparison is not between two wrong answers
    assert np.all(np.abs(td.theta - truth) < 4 * se)
    # the chi-square of the weighted line residual is consistent with the periods' noise
    assert fd.extras["chi_square_p"] > 1e-3


def test_polished_frequency_domain_estimate_is_the_time_domain_minimum():
    model, truth = potato()
    problem, _ = record(model, truth, order=7, bit=2.5e-6, fs=1.6e6, n=508 * 4, noise=0.02, seed=5)
    problem.initial = truth * 1.2
    td = ScipyLM(ScipyLMOptions()).solve(problem)
    fd = FrequencyDomain(FrequencyDomainOptions()).solve(problem)
    np.testing.assert_allclose(fd.theta, td.theta, rtol=1e-4)
    assert fd.cost <= td.cost * (1 + 1e-6)


def test_frequency_domain_refuses_a_record_that_is_not_periodic():
    from mbus_framework.errors import EstimationError

    model, truth = potato()
    problem, _ = record(model, truth, order=9, bit=2.5e-6, fs=1.6e6, n=3000, noise=0.02, seed=5)
    with pytest.raises(EstimationError, match="not periodic"):
        FrequencyDomain(FrequencyDomainOptions()).solve(problem)


def _pipeline_fit(noise, n, seed, n_elements=3, order=9):
    model, truth = potato(n_elements)
    problem, _ = record(model, truth, order=order, bit=2.5e-6, fs=6.25e6, n=n, noise=noise, seed=seed)
    return fit(problem.t, problem.u, problem.y, sample=GEOMETRY, model_options={"n_elements": n_elements},
               config={"uncertainty": {"profile": True}}, plots=False), truth


def test_profile_intervals_match_the_linearised_ones_on_a_well_identified_record():
    result, truth = _pipeline_fit(noise=0.01, n=4000, seed=3)
    unc = result.document["uncertainty"]
    assert set(unc["profile_ci"]) == {"k_sigma", "b_sigma", "k_tau", "b_tau"}
    for name, (lo, hi) in unc["profile_ci"].items():
        lin_lo, lin_hi = unc["ci95"][name]
        half = 0.5 * (lin_hi - lin_lo)
        assert lo is not None and hi is not None
        assert abs(lo - lin_lo) < 0.25 * half and abs(hi - lin_hi) < 0.25 * half, (name, (lo, hi), (lin_lo, lin_hi))
    assert not any(unc["profile_disagrees"].values())
    assert not [w for w in result.warnings if "profile-likelihood" in w]


def test_profile_intervals_differ_and_warn_on_a_badly_identified_record():
    """A short record at 60 % noise: the cost is far from quadratic over the interval."""
    result, truth = _pipeline_fit(noise=0.6, n=600, seed=4)
    unc = result.document["uncertainty"]
    flagged = [n for n, bad in unc["profile_disagrees"].items() if bad]
    assert flagged, (unc["profile_ci"], unc["ci95"])
    warned = [w for w in result.warnings if "profile-likelihood interval" in w]
    assert len(warned) == len(flagged) and all(any(n in w for w in warned) for n in flagged)


@pytest.mark.parametrize("case", ["noise only", "300 % noise", "1000 % noise"])
def test_no_parameter_without_a_warning_when_the_record_holds_no_information(case):
    model, truth = potato()
    problem, sigma = record(model, truth, order=9, bit=2.5e-6, fs=6.25e6, n=3000, noise=3.0, seed=8)
    y = problem.y
    if case == "noise only":
        y = np.random.default_rng(9).normal(0, 1.0, y.size)
    elif case == "1000 % noise":
        y = problem.y + np.random.default_rng(10).normal(0, 3.0 * sigma, y.size)
    result = fit(problem.t, problem.u, y, sample=GEOMETRY, plots=False)
    assert result.document["fit"]["reliable"] is False
    names = ["k_sigma", "b_sigma", "k_tau", "b_tau"]
    unreliable = [w for w in result.warnings if "not reliable" in w]
    assert unreliable and all(n in unreliable[0] for n in names), result.warnings


def test_a_clean_record_passes_the_information_gate():
    model, truth = potato()
    problem, _ = record(model, truth, order=9, bit=2.5e-6, fs=6.25e6, n=3000, noise=0.05, seed=8)
    result = fit(problem.t, problem.u, problem.y, sample=GEOMETRY, plots=False)
    assert result.document["fit"]["reliable"] is True
    assert not [w for w in result.warnings if "not reliable" in w]
