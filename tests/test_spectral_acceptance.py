"""The record's spectra (estimation.spectral) and the noise-level acceptance (estimation.acceptance)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats
from scipy.signal import lfilter, max_len_seq

from mbus_framework.estimation.acceptance import estimate_noise, judge, out_of_band_variance, residual_input_test
from mbus_framework.estimation.spectral import detect_period, dtft, periodic_lines


def prbs(order, samples_per_bit, n, state=None):
    seq = max_len_seq(order, state=state)[0] * 2.0 - 1.0
    return seq[(np.arange(n) // samples_per_bit) % seq.size]


def test_dtft_equals_the_fft_on_its_bins():
    x = np.random.default_rng(0).normal(size=3000)
    k = np.arange(0, 1500, 37)
    dt = 1e-7
    assert dtft(x, k / (x.size * dt), dt, chunk=512) == pytest.approx(np.fft.rfft(x)[k], rel=1e-9, abs=1e-9)


@settings(max_examples=20, deadline=None)
@given(st.integers(5, 9), st.integers(1, 12), st.floats(2.2, 5.0))
def test_detect_period_finds_the_prbs_period(order, spb, periods):
    P = (2**order - 1) * spb
    u = prbs(order, spb, int(periods * P))
    u = u + np.random.default_rng(order).normal(0, 0.05, u.size)  # a recorded, noisy input
    assert detect_period(u) == P


def test_no_period_in_a_record_shorter_than_two_periods_or_in_noise():
    assert detect_period(prbs(11, 10, 6200)) is None
    assert detect_period(np.random.default_rng(3).normal(size=5000)) is None


def test_periodic_lines_give_the_noise_variance():
    rng = np.random.default_rng(5)
    P, M = 1270, 8
    u = prbs(7, 10, P * M)
    y = lfilter([0.2, 0.5, 0.2], [1.0, -0.6], u) + rng.normal(0, 0.3, u.size)
    lines = periodic_lines(u, y, 1e-7)
    assert lines.period == P and lines.periods == M - 1 and lines.skipped == 1
    dof = P * (lines.periods - 1)
    assert lines.noise_var == pytest.approx(0.09, rel=5 * np.sqrt(2 / dof))
    # averaged lines are the filter's response times the input lines
    from scipy.signal import freqz

    _, H = freqz([0.2, 0.5, 0.2], [1.0, -0.6], worN=2 * np.pi * lines.f * 1e-7)
    strong = np.abs(H * lines.U) > 0.3 * np.abs(H * lines.U).max()
    rel = np.abs(lines.Y - H * lines.U)[strong] / np.abs(H * lines.U)[strong]
    assert strong.sum() > 20 and np.median(rel) < 0.05


def test_out_of_band_noise_of_a_chain_record():
    """A 10-element chain rolls off steeply: at 5 % noise the top quarter of a 25 MS/s record
    is noise. (At 1 % noise a lightly damped slice still leaks signal there: the estimate is
    then high, which is why it is reported, not used to accept a minimum.)"""
    from mbus_framework.engine.simulation import simulate
    from mbus_framework.interfaces.sample import Sample
    from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

    model = KelvinVoigtChain(Sample(0.03, 0.0254, 1080.0), KelvinVoigtOptions(n_elements=10))
    theta = model.from_properties(dict(E_sigma=2.42e10, eta_sigma=7.18e3, E_tau=6.56e9, eta_tau=5.14e3))
    u = prbs(9, 10, 6200)
    y0 = simulate(model, theta, u, 4e-8)
    sigma = 0.05 * np.sqrt(np.mean(y0**2))
    y = y0 + np.random.default_rng(2).normal(0, sigma, u.size)
    assert np.sqrt(out_of_band_variance(y)) == pytest.approx(sigma, rel=0.1)


def test_residual_input_test_is_calibrated_under_pure_noise():
    """The FIR part's p-values of pure-noise residuals are uniform; the combined test (with the
    Bonferroni-bounded cross-correlation over all lags) is conservative: it rejects noise at
    most as often as its level says."""
    rng = np.random.default_rng(11)
    u = prbs(9, 10, 5000)
    tests = [residual_input_test(rng.normal(size=u.size), u, 4, lags=100) for _ in range(200)]
    p_fir = np.array([t.p_fir for t in tests])
    p = np.array([t.p_value for t in tests])
    assert 0.01 <= np.mean(p_fir < 0.05) <= 0.10
    assert stats.kstest(p_fir, "uniform").pvalue > 1e-3
    assert np.mean(p < 0.05) <= 0.07 and np.mean(p < 1e-3) == 0.0


def test_a_late_arrival_beyond_the_fir_lags_is_seen():
    """A leftover echo 1500 samples late (a slow wave): outside the FIR's lags, inside the
    cross-correlation's."""
    rng = np.random.default_rng(8)
    u = prbs(11, 10, 6200)
    echo = np.r_[np.zeros(1500), u[:-1500]] * 0.15  # 2 % of the noise power
    t = residual_input_test(rng.normal(size=u.size) + echo, u, 4)
    assert t.lags < 1500 and t.p_fir > 1e-3
    assert t.p_value < 1e-4 and abs(t.max_lag - 1500) <= 10


def test_residual_input_test_sees_a_misfit_that_whiteness_misses():
    """A leftover filtered copy of the input with a tenth of the noise power: white-looking,
    rejected by the input-residual test (the failure mode of accepting on whiteness)."""
    from mbus_framework.estimation.exploration import residual_autocorrelation

    rng = np.random.default_rng(4)
    u = prbs(11, 10, 6200)
    leftover = lfilter(np.hanning(40), [1.0], u)  # a band-limited echo of the signal
    leftover *= np.sqrt(0.1) / leftover.std()
    r = rng.normal(size=u.size) + leftover
    assert residual_autocorrelation(r) < 0.1  # passes the old whiteness test
    v = judge(r, u, 4, None)
    assert not v.accepted and "input-related" in v.reason
    assert judge(rng.normal(size=u.size), u, 4, None).accepted


def test_judge_uses_the_noise_of_repeated_periods():
    rng = np.random.default_rng(9)
    P, M = 1270, 6
    u = prbs(7, 10, P * M)
    y = lfilter([0.3], [1.0, -0.5], u) + rng.normal(0, 0.1, u.size)
    noise = estimate_noise(np.arange(u.size) * 1e-7, u, y)
    assert np.sqrt(noise.periods) == pytest.approx(0.1, rel=0.1)
    white = rng.normal(0, 0.1, u.size)
    assert judge(white, u, 4, noise).accepted
    too_big = rng.normal(0, 0.13, u.size)  # residual 30 % above the period scatter
    v = judge(too_big, u, 4, noise)
    assert not v.accepted and "repeated periods" in v.reason


def test_significant_but_small_structure_does_not_reject_a_minimum():
    """Significance is not size: on a long record a leftover with 1 % of the noise power is
    significant (p < 1e-3) but removes ~1 % of the residual energy, below min_excess (3 %): the
    minimum is accepted and the reason says why. With min_excess 0 it is rejected, and a
    leftover at 15 % of the noise power is rejected either way."""
    rng = np.random.default_rng(21)
    u = prbs(13, 4, 60000)
    shape = lfilter(np.hanning(40), [1.0], u)
    shape /= shape.std()
    noise = rng.normal(size=u.size)
    small = noise + np.sqrt(0.01) * shape
    t = residual_input_test(small, u, 4)
    assert t.p_value < 1e-3 and 0.002 < t.excess_fraction < 0.02
    v = judge(small, u, 4, None)
    assert v.accepted and "significant but small" in v.reason
    assert not judge(small, u, 4, None, min_excess=0.0).accepted
    large = noise + np.sqrt(0.15) * shape
    assert judge(large, u, 4, None).residual_test.excess_fraction > 0.1
    assert not judge(large, u, 4, None).accepted
