"""python-control export, frequency responses and the Bode report figure."""
from __future__ import annotations

import control
import numpy as np
import pytest

from mbus_framework.engine.control_interop import (
    bode_figure,
    frequency_response,
    to_control,
    transfer_function_estimate,
    write_bode_plot,
)
from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import simulate
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.models.maxwell import MaxwellChain, MaxwellOptions
from mbus_plugins.models.sls import SlsChain, SlsOptions

SAMPLE = Sample(length=0.05, diameter=0.0254, density=1000.0)
DT = 1 / 6.25e6
MODELS = [
    (KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=10)), [3e8, 15.0, 5e7, 12.0]),
    (MaxwellChain(SAMPLE, MaxwellOptions(n_elements=6)), [3e8, 900.0, 5e7, 500.0]),
    (SlsChain(SAMPLE, SlsOptions(n_elements=8)), [2e8, 1e8, 300.0, 4e7, 1e7, 100.0]),
]


@pytest.mark.parametrize("model,theta", MODELS)
def test_continuous_export_matches_model(model, theta):
    sys = to_control(model, theta)
    assert isinstance(sys, control.StateSpace) and sys.dt == 0
    A, B, C, D = model.state_space(np.asarray(theta))
    np.testing.assert_array_equal(sys.A, A)
    np.testing.assert_array_equal(sys.C, C)
    f = np.logspace(3, 6.5, 80)
    ours = frequency_response(model, theta, f)
    theirs = np.squeeze(control.frequency_response(sys, 2 * np.pi * f).complex)
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-12 * np.max(np.abs(theirs)))
    # Near DC a Maxwell column flows: every link acts as its dashpot, so it transmits like a
    # chain of dashpots (KV with zero springs); spring-anchored chains pass a static fraction.
    dc = frequency_response(model, theta, [1e-3])[0]
    if isinstance(model, MaxwellChain):
        n = model.n
        dashpots = frequency_response(KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n)),
                                      [0.0, theta[1], 0.0, theta[3]], [1e-3])[0]
        assert dc == pytest.approx(dashpots, rel=1e-6)
    else:
        assert 0 < dc.real < 1


@pytest.mark.parametrize("model,theta", MODELS)
def test_discrete_export_is_the_zoh_simulator(model, theta):
    sysd = to_control(model, theta, DT)
    assert sysd.dt == DT
    u = np.repeat(np.random.default_rng(0).choice([-1.0, 1.0], 120), 15)
    t = np.arange(u.size) * DT
    _, y_ctrl = control.forced_response(sysd, T=t, U=u)
    y = simulate(model, theta, u, DT)
    assert np.max(np.abs(y_ctrl - y)) < 1e-10 * np.max(np.abs(y))
    f = np.linspace(1e3, 3e6, 50)
    Hd = frequency_response(model, theta, f, dt=DT)
    theirs = np.squeeze(control.frequency_response(sysd, 2 * np.pi * f).complex)
    np.testing.assert_allclose(Hd, theirs, rtol=1e-8, atol=1e-10 * np.max(np.abs(theirs)))


def test_transfer_function_estimate_sees_the_model():
    model, theta = MODELS[2]
    u = np.repeat(np.random.default_rng(0).choice([-1.0, 1.0], 20000 // 15 + 1), 15)[:20000]
    y = simulate(model, theta, u, DT)
    y = y + np.random.default_rng(1).normal(0, 0.02 * np.std(y), y.shape)
    est = transfer_function_estimate(u, y, DT, nperseg=4096)
    H = frequency_response(model, theta, est.f, dt=DT)
    good = (est.coherence > 0.9) & (np.abs(H) > 0.05 * np.max(np.abs(H)))
    assert good.sum() > 10
    err_db = np.abs(20 * np.log10(np.abs(est.H[good]) / np.abs(H[good])))
    assert np.median(err_db) < 1.0 and np.max(err_db) < 3.0
    # a different medium is visibly different
    H_other = frequency_response(*MODELS[0], est.f, dt=DT)
    assert np.median(np.abs(20 * np.log10(np.abs(est.H[good]) / np.abs(H_other[good])))) > 3.0


def test_bode_plot_of_fit_against_measurement(tmp_path):
    model, theta = MODELS[0]
    u = np.repeat(np.random.default_rng(2).choice([-1.0, 1.0], 600), 15)
    y = simulate(model, theta, u, DT)
    fig = bode_figure(model, theta, u, y, DT, title="fit vs measurement",
                      extra_models=[("maxwell", *MODELS[1])])
    ax_mag, ax_phase = fig.axes
    labels = [line.get_label() for line in ax_mag.get_lines()]
    assert "fitted model" in labels and "maxwell" in labels and "measured (H1 estimate)" in labels
    assert ax_mag.get_xscale() == "log"
    path = write_bode_plot(tmp_path / "bode.png", model, theta, u, y, DT)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # model only (no record): a continuous-time Bode diagram
    assert len(bode_figure(model, theta).axes[0].get_lines()) == 1
