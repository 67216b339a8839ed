"""Virtual transducer pair and scope of the ``simulated`` rig: band-pass responses, exact
cascade simulation, mismatch, ADC quantisation, averaging, trigger delay, plane-wave medium."""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.compensation.filters import SpectralFilter
from mbus_framework.engine.hold import hold_response
from mbus_framework.engine.simulation import simulate, simulate_ss
from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_framework.interfaces.sample import Sample
from mbus_framework.pipeline.config import validate_options
from mbus_plugins.backends.transducers import (
    BandPass,
    TransducerPair,
    TransducerPairOptions,
    series,
)
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

SAMPLE = Sample(0.03, 0.0254, 1080.0)
PROPS = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}
FS = 25e6


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_manager(new_plugin_manager())


@pytest.fixture(scope="module")
def waveform():
    return Prbs(PrbsOptions(order=8, bit_width=0.4e-6, sample_rate=FS, n_samples=3000)).waveform()


def model() -> KelvinVoigtChain:
    return KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=6))


def acquire(registry, waveform, options, sample=SAMPLE):
    cls = registry.get("backend", "simulated").implementation
    backend = cls(validate_options(cls.Options, options, "backend.options"))
    return backend, backend.acquire(AcquisitionContext(waveform, sample, model(), registry))


def frequency_response(ss, f):
    A, B, C, D = ss
    return np.array([(C @ np.linalg.solve(2j * np.pi * fk * np.eye(A.shape[0]) - A, B) + D).item() for fk in f])


@pytest.mark.parametrize("fc, bw, gain, order", [(0.5e6, 0.4e6, 1.0, 2), (1.0e6, 0.3e6, 0.2, 3), (0.25e6, 0.4e6, 5.0, 1)])
def test_band_pass_centre_gain_edges_and_state_space(fc, bw, gain, order):
    bp = BandPass(fc, bw, gain, order)
    f1, f2 = bp.edges
    assert f1 * f2 == pytest.approx(fc**2) and f2 - f1 == pytest.approx(bw)
    h = bp.response(np.array([fc, f1, f2, 0.01 * f1, 100 * f2]))
    assert abs(h[0]) == pytest.approx(gain, rel=1e-9) and abs(np.angle(h[0])) < 1e-9
    np.testing.assert_allclose(np.abs(h[1:3]), gain / np.sqrt(2), rtol=1e-9)  # -3 dB edges
    assert np.all(np.abs(h[3:]) < gain * 0.02 ** order)  # N-th order roll-off on both sides
    f = np.linspace(0.05, 3, 40) * fc
    np.testing.assert_allclose(frequency_response(bp.state_space(), f), bp.response(f), rtol=1e-9, atol=1e-12 * gain)


def test_mismatch_splits_the_pair_and_the_pair_response_is_the_product():
    o = TransducerPairOptions(mismatch={"centre_frequency": 0.1, "bandwidth": -0.2, "gain": 0.5})
    pair = TransducerPair(o)
    assert pair.transmitter.centre_frequency == pytest.approx(0.5e6 * 1.05)
    assert pair.receiver.centre_frequency == pytest.approx(0.5e6 * 0.95)
    assert pair.transmitter.bandwidth == pytest.approx(0.4e6 * 0.9)
    assert pair.receiver.gain == pytest.approx(0.75)
    f = np.linspace(0.1e6, 1.5e6, 50)
    np.testing.assert_allclose(pair.response(f), pair.transmitter.response(f) * pair.receiver.response(f))
    identical = TransducerPair(TransducerPairOptions())
    lo, hi = identical.band()
    assert lo == pytest.approx(identical.transmitter.edges[0], rel=2e-3)  # -6 dB of the pair = -3 dB of each
    assert hi == pytest.approx(identical.transmitter.edges[1], rel=2e-3)
    assert pair.describe()["transmitter"]["gain"] == pytest.approx(1.25)


def test_rig_with_transducers_is_the_exact_cascade(registry, waveform):
    opts = {"truth": PROPS, "noise": {"relative_std": 0.0}, "transducers": {"mismatch": {"centre_frequency": 0.05}}}
    backend, m = acquire(registry, waveform, opts)
    pair = backend.pair
    theta = model().from_properties(PROPS)
    cascade = series(series(pair.transmitter.state_space(), model().state_space(theta)), pair.receiver.state_space())
    np.testing.assert_array_equal(m.y, simulate_ss(cascade, waveform.u, waveform.dt))
    # LTI: the same as filtering the bare medium output by G_T G_R (FFT filter, to aliasing error).
    bare = simulate(model(), theta, waveform.u, waveform.dt)
    filtered = SpectralFilter(pair.response)(bare, waveform.dt)
    assert np.max(np.abs(filtered - m.y)) < 1e-5 * np.max(np.abs(m.y))
    assert m.truth == pytest.approx(dict(zip(model().parameter_names, theta)))
    assert m.meta["transducers"]["name"] == "virtual 0.5 MHz pair"
    G = backend.true_transducer_response(np.array([0.5e6]))
    assert abs(G[0]) == pytest.approx(abs(pair.response([0.5e6])[0]))


def test_sine_through_the_pair_has_the_pair_gain_and_phase(registry):
    """Steady state of a sampled sine through the exact ZOH cascade: gain and phase of G_TR
    times the hold's e^{-i pi f h} sinc(f h)."""
    f0, n = 0.6e6, 12500
    t = np.arange(n) / FS
    from mbus_framework.interfaces.excitation import Waveform

    w = Waveform(t, np.sin(2 * np.pi * f0 * t))
    opts = {"wave": {"attenuation": 0.0}, "noise": {"relative_std": 0.0}, "transducers": {"order": 3}}
    backend, m = acquire(registry, w, opts, sample=Sample(0.0, 0.0254, 998.0))
    H = backend.true_transducer_response(np.array([f0]))[0] * hold_response(np.array([f0]), 1 / FS)[0]
    expected = np.imag(H * np.exp(2j * np.pi * f0 * t))
    np.testing.assert_allclose(m.y[-3000:], expected[-3000:], atol=1e-9)


def test_plane_wave_medium_delays_and_attenuates(registry, waveform):
    L = 0.0148  # 10 us in water at 1480 m/s: 250 samples
    opts = {"wave": {"sound_speed": 1480.0, "attenuation": 0.0}, "noise": {"relative_std": 0.0}}
    _, m = acquire(registry, waveform, opts, sample=Sample(L, 0.0254, 998.0))
    np.testing.assert_array_equal(m.y[250:], waveform.u[:-250])
    assert np.all(m.y[:250] == 0) and m.truth is None
    assert m.meta["true_properties"]["sound_speed"] == 1480.0
    # Attenuation alpha_1 (f/1MHz)^2: a burst that ends well inside the record keeps its whole
    # response, so the spectra's ratio is the zero-phase factor exp(-L alpha(f)).
    from mbus_framework.interfaces.excitation import Waveform

    u = np.where(np.arange(3000) < 600, waveform.u, 0.0)
    burst = Waveform(waveform.t, u)
    lossless = {"wave": {"sound_speed": 1480.0, "attenuation": 0.0}, "noise": {"relative_std": 0.0}}
    lossy = {"wave": {"sound_speed": 1480.0, "attenuation": 200.0}, "noise": {"relative_std": 0.0}}
    _, m0 = acquire(registry, burst, lossless, sample=Sample(L, 0.0254, 998.0))
    _, a = acquire(registry, burst, lossy, sample=Sample(L, 0.0254, 998.0))
    f = np.fft.rfftfreq(3000, waveform.dt)
    Y0 = np.fft.rfft(m0.y)
    sel = (f > 0.1e6) & (f < 1.5e6) & (np.abs(Y0) > 1e-2 * np.abs(Y0).max())
    ratio = np.fft.rfft(a.y)[sel] / Y0[sel]
    np.testing.assert_allclose(ratio, np.exp(-L * 200.0 * (f[sel] / 1e6) ** 2), rtol=1e-3, atol=1e-4)
    with pytest.raises(ConfigError, match="leave out truth"):
        acquire(registry, waveform, {"wave": {}, "truth": PROPS})


def test_adc_quantises_both_channels_on_their_ranges(registry, waveform):
    opts = {"truth": PROPS, "noise": {"relative_std": 0.0}, "scope": {"bits": 8, "output_range": 0.01, "input_range": 2.0}}
    _, m = acquire(registry, waveform, opts)
    qy, qu = 0.01 / 128, 2.0 / 128
    np.testing.assert_allclose(m.y / qy, np.round(m.y / qy), atol=1e-9)
    np.testing.assert_allclose(m.u / qu, np.round(m.u / qu), atol=1e-9)
    clean = simulate(model(), model().from_properties(PROPS), waveform.u, waveform.dt)
    assert np.max(np.abs(m.y - np.clip(clean, -0.01, 0.01 - qy))) <= qy / 2 + 1e-15
    assert m.meta["scope"]["output_step"] == pytest.approx(qy)
    assert m.meta["scope"]["clipped_output_samples"] == int(np.sum((np.round(clean / qy) < -128) | (np.round(clean / qy) > 127)))
    # Default ranges: 1.25 x the noise-free peaks, no clipping.
    _, d = acquire(registry, waveform, {"truth": PROPS, "noise": {"relative_std": 0.0}, "scope": {}})
    assert d.meta["scope"]["output_range"] == pytest.approx(1.25 * np.max(np.abs(clean)))
    assert d.meta["scope"]["clipped_output_samples"] == 0


def test_averaging_shots_with_independent_noise(registry):
    """Std of (record - clean) falls as 1/sqrt(averages); the reported noise_std follows
    sqrt((sigma^2 + q^2/12) / averages). 20000 samples: std estimates within ~1 %."""
    w = Prbs(PrbsOptions(order=12, bit_width=0.4e-6, sample_rate=FS, n_samples=20000)).waveform()
    clean = simulate(model(), model().from_properties(PROPS), w.u, w.dt)
    stds = {}
    for n in (1, 16):
        opts = {"truth": PROPS, "noise": {"relative_std": 0.1}, "scope": {"bits": 12, "averages": n}, "seed": 4}
        _, m = acquire(registry, w, opts)
        stds[n] = np.std(m.y - clean)
        assert stds[n] == pytest.approx(m.meta["noise_std"], rel=0.05)
        assert m.meta["noise_std_per_shot"] == pytest.approx(0.1 * np.sqrt(np.mean(clean**2)))
    assert stds[1] / stds[16] == pytest.approx(4.0, rel=0.05)


def test_trigger_delay_shifts_both_channels(registry, waveform):
    base = {"truth": PROPS, "noise": {"relative_std": 0.0}, "transducers": {}}
    _, a = acquire(registry, waveform, base)
    _, b = acquire(registry, waveform, {**base, "scope": {"bits": 16, "trigger_delay": 40 * 40e-9}})
    qy = b.meta["scope"]["output_step"]
    np.testing.assert_allclose(b.y[40:], a.y[:-40], atol=qy)
    assert np.all(b.u[:40] == 0)
    np.testing.assert_allclose(b.u[40:], a.u[:-40], atol=b.meta["scope"]["input_step"])
    # A fractional trigger delay is exact too (continuous-time readout between samples).
    _, c = acquire(registry, waveform, {**base, "scope": {"bits": 16, "trigger_delay": 40.5 * 40e-9}})
    assert np.max(np.abs(c.y[41:] - 0.5 * (a.y[:-41] + a.y[1:-40]))) < 0.05 * np.max(np.abs(a.y))


def test_absent_options_leave_the_record_unchanged(registry, waveform):
    opts = {"truth": PROPS, "noise": {"relative_std": 0.05}, "seed": 3}
    _, a = acquire(registry, waveform, opts)
    clean = simulate(model(), model().from_properties(PROPS), waveform.u, waveform.dt)
    rng = np.random.default_rng(3)
    sigma = 0.05 * np.sqrt(np.mean(clean**2))
    np.testing.assert_array_equal(a.y, clean + rng.normal(0.0, sigma, clean.shape))
    assert "transducers" not in a.meta and "scope" not in a.meta


@pytest.mark.parametrize(
    "options, fragment",
    [
        ({"truth": PROPS, "transducers": {"centre_frequncy": 1e6}}, "did you mean 'centre_frequency'"),
        ({"truth": PROPS, "scope": {"bits": 1}}, "backend.options.scope.bits"),
        ({"truth": PROPS, "scope": {"averages": 0}}, "backend.options.scope.averages"),
        ({"truth": PROPS, "scope": {"trigger_delay": 1e-6}, "hold": "foh"}, "need hold: zoh"),
        ({"wave": {}, "hold": "foh"}, "wave needs hold: zoh"),
        ({"truth": PROPS, "transducers": {"mismatch": {"gain": 2.0}}}, "backend.options.transducers.mismatch.gain"),
    ],
)
def test_option_errors_name_the_key(registry, options, fragment):
    cls = registry.get("backend", "simulated").implementation
    with pytest.raises(ConfigError, match=fragment) as info:
        validate_options(cls.Options, options, "backend.options")
    assert "\n" not in str(info.value)
