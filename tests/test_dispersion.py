"""Dispersion of fitted chains (pipeline.dispersion) against the closed-form plane wave of the
continuum their normal properties describe."""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.interfaces.sample import Sample
from mbus_framework.pipeline.dispersion import NP_TO_DB_PER_CM, dispersion_section, input_band, summary_line
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.models.maxwell import MaxwellChain, MaxwellOptions

SAMPLE = Sample(0.03, 0.0254, 1080.0)


def _plane_wave(M, f, rho):
    w = 2 * np.pi * f
    k = w * np.sqrt(rho / M)
    return w / k.real, -k.imag * NP_TO_DB_PER_CM


def _tone_burst(fc=1e6, dt=4e-8, n=4096):
    t = np.arange(n) * dt
    return np.exp(-(((t - 20e-6) * fc) ** 2)) * np.sin(2 * np.pi * fc * t), dt


@pytest.mark.parametrize("E,eta", [(2.42e10, 7180.0), (3e9, 50.0), (8e8, 2e3)])
def test_kelvin_voigt_chain_gives_the_kelvin_voigt_continuum(E, eta):
    model = KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=10))
    theta = np.asarray(model.from_properties(dict(E_sigma=E, eta_sigma=eta, E_tau=E / 4, eta_tau=eta)))
    u, dt = _tone_burst()
    d = dispersion_section(model, theta, u, dt)
    f = np.array(d["frequency_Hz"])
    c, a = _plane_wave(E + 2j * np.pi * f * eta, f, SAMPLE.density)
    np.testing.assert_allclose(d["phase_velocity_m_s"], c, rtol=1e-10)
    np.testing.assert_allclose(d["attenuation_dB_per_cm"], a, rtol=1e-8, atol=1e-12)


def test_maxwell_chain_gives_the_maxwell_continuum():
    model = MaxwellChain(SAMPLE, MaxwellOptions(n_elements=6))
    props = {p.name: 1.0 for p in model.properties}
    props.update(E_sigma=5e9, eta_sigma=2e4)
    for name in props:
        if name.endswith("_tau"):
            props[name] = 1e9 if name.startswith("E") else 1e4
    theta = np.asarray(model.from_properties(props))
    u, dt = _tone_burst()
    d = dispersion_section(model, theta, u, dt)
    f = np.array(d["frequency_Hz"])
    iw = 2j * np.pi * f
    M = iw * 2e4 * 5e9 / (5e9 + iw * 2e4)
    c, a = _plane_wave(M, f, SAMPLE.density)
    np.testing.assert_allclose(d["phase_velocity_m_s"], c, rtol=1e-10)
    np.testing.assert_allclose(d["attenuation_dB_per_cm"], a, rtol=1e-8)


def test_band_follows_the_input_spectrum():
    u, dt = _tone_burst(fc=1e6)
    lo, hi = input_band(u, dt)
    assert lo < 1e6 < hi and hi - lo < 2e6  # a Gaussian burst of width 1/fc: about +-0.8 MHz at -20 dB
    assert input_band(np.zeros(100), dt) is None


def test_standard_errors_follow_the_covariance_and_print_at_the_band_centre():
    model = KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=10))
    theta = np.asarray(model.from_properties(dict(E_sigma=3e9, eta_sigma=50.0, E_tau=1e9, eta_tau=50.0)))
    u, dt = _tone_burst()
    free = np.array([True, False, False, False])
    rel = 0.01  # 1 % on k_sigma alone, i.e. 1 % on E_sigma
    d = dispersion_section(model, theta, u, dt, free, np.array([[(rel * theta[0]) ** 2]]))
    f = np.array(d["frequency_Hz"])
    up, dn = (_plane_wave(3e9 * (1 + s * 1e-6) + 2j * np.pi * f * 50.0, f, SAMPLE.density)[0] for s in (1, -1))
    expected = np.abs(up - dn) / 2e-6 * rel  # delta method on the closed form
    np.testing.assert_allclose(d["phase_velocity_se_m_s"], expected, rtol=1e-4)
    assert np.all(np.abs(np.array(d["phase_velocity_se_m_s"]) / np.array(d["phase_velocity_m_s"]) - 0.005) < 5e-4)
    assert "band centre" in summary_line(d) and "m/s" in summary_line(d) and "dB/cm" in summary_line(d)
