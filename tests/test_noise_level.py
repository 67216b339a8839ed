"""The model-free noise level (estimation.noise_level) on records of known noise, made from the
physics by an independent simulator (scipy's exact ZOH discretisation and dlsim)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import signal
from scipy.signal import max_len_seq

from mbus_framework.estimation.acceptance import estimate_noise, out_of_band_variance
from mbus_framework.estimation.noise_level import local_polynomial_variance
from mbus_framework.estimation.routing import least_damping
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

SETTINGS = {"2.5us@6.25MS/s": (2.5e-6, 6.25e6), "0.4us@25MS/s": (0.4e-6, 25e6)}
N = 6200
# (length [m], density [kg/m^3], elements, properties): a potato slice (heavily damped), water,
# and a nearly undamped slice that rings through the whole record
CHAINS = {
    "potato": (0.03, 1080.0, 10, dict(E_sigma=2.42e10, eta_sigma=7.18e3, E_tau=6.56e9, eta_tau=5.14e3)),
    "water": (0.05, 998.0, 6, dict(E_sigma=2.2e9, eta_sigma=1.0, E_tau=2.2e9, eta_tau=1.0)),
    "ringing": (0.006, 1100.0, 4, dict(E_sigma=4.0e9, eta_sigma=0.05, E_tau=1.0e9, eta_tau=0.05)),
}


def record(chain: str, setting: str, order: int, noise: float, seed: int = 0):
    """(u, y, sigma, least damping ratio of the chain): a PRBS of LFSR ``order`` held for the
    setting's bit (a fractional number of samples at 6.25 MS/s), white noise ``noise`` x the
    output RMS."""
    length, density, n, props = CHAINS[chain]
    model = KelvinVoigtChain(Sample(length, 0.0254, density), KelvinVoigtOptions(n_elements=n))
    theta = np.asarray(model.from_properties(props), float)
    bit, fs = SETTINGS[setting]
    seq = max_len_seq(order)[0] * 2.0 - 1.0
    t = np.arange(N) / fs
    u = seq[np.floor(t / bit + 1e-9).astype(int) % seq.size]
    A, B, C, D = (np.asarray(x, float) for x in model.state_space(theta))
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, B, C, D), 1 / fs, method="zoh")
    y0 = signal.dlsim((Ad, Bd, Cd, Dd, 1 / fs), u)[1].ravel()
    sigma = noise * float(np.sqrt(np.mean(y0**2)))
    y = y0 + np.random.default_rng(seed).normal(0.0, sigma, N)
    return t, u, y, sigma, least_damping(np.linalg.eigvals(Ad), 1 / fs)


@pytest.mark.parametrize("chain", sorted(CHAINS))
@pytest.mark.parametrize("setting", sorted(SETTINGS))
@pytest.mark.parametrize("order", [7, 9, 11])
@pytest.mark.parametrize("noise", [0.001, 0.02, 0.2])
def test_local_polynomial_noise_of_chain_records(chain, setting, order, noise):
    t, u, y, sigma, _ = record(chain, setting, order, noise, seed=order)
    assert np.sqrt(local_polynomial_variance(u, y)) == pytest.approx(sigma, rel=0.1)
    est = estimate_noise(t, u, y)
    assert np.sqrt(est.out_of_band) == pytest.approx(sigma, rel=0.1)
    if est.periods is not None:  # only steady periods give a noise estimate
        assert np.sqrt(est.periods) == pytest.approx(sigma, rel=0.1)


def test_the_ringing_chain_rings_and_defeats_the_top_of_the_spectrum():
    """The cases above include what the old estimators got wrong: a chain ringing through the
    record (damping ratio below routing's 0.002), whose periods never become steady, and a
    broadband record whose top spectral quarter holds signal."""
    t, u, y, sigma, zeta = record("ringing", "0.4us@25MS/s", 7, 0.02)
    assert zeta < 0.002
    from mbus_framework.estimation.spectral import periodic_lines

    scatter = periodic_lines(u, y, t[1] - t[0]).noise_var
    assert scatter > 4 * sigma**2  # the period scatter holds the ringing start ...
    assert estimate_noise(t, u, y).periods is None  # ... and is not taken for the noise
    t, u, y, sigma, _ = record("water", "2.5us@6.25MS/s", 7, 0.001)
    assert out_of_band_variance(y) > 4 * sigma**2  # at 0.1 % noise the top quarter is signal


def test_pure_noise_and_a_silent_input():
    rng = np.random.default_rng(4)
    y = rng.normal(0.0, 0.3, 5000)
    for u in (np.sign(rng.normal(size=5000)), np.zeros(5000)):
        assert np.sqrt(local_polynomial_variance(u, y)) == pytest.approx(0.3, rel=0.06)
    assert local_polynomial_variance(np.ones(40), np.ones(40)) is None
