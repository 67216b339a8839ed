"""``prbs`` excitation: maximal length, levels, sample timing, length options, spectrum (Fig. 3.7)."""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from mbus_framework.pipeline.config import validate_options
from mbus_framework.errors import ConfigError
from mbus_framework.interfaces.excitation import power_spectrum
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions, mls_bits


def prbs(**options) -> Prbs:
    """Build the plugin as a run does: options validated by the stage-2 validator."""
    return Prbs(validate_options(PrbsOptions, options, "excitation.options"))


@pytest.mark.parametrize("order", range(3, 21))
def test_lfsr_sequence_has_maximal_length(order):
    bits = mls_bits(order)
    N = 2**order - 1
    assert bits.shape == (N,)
    assert set(np.unique(bits)) == {0, 1}
    # Balance: an m-sequence has 2^(n-1) ones and 2^(n-1) - 1 zeros per period.
    assert int(bits.sum()) == 2 ** (order - 1)
    # Two-valued periodic autocorrelation (N at lag 0, -1 at every other lag) holds for
    # m-sequences only; it also proves that no shorter period exists.
    s = 2.0 * bits - 1.0
    S = np.fft.rfft(s)
    acf = np.fft.irfft(S * np.conj(S), N)
    assert acf[0] == pytest.approx(N)
    np.testing.assert_allclose(acf[1:], -1.0, atol=1e-6 * N)


@pytest.mark.parametrize("order", [3, 4, 7, 10])
def test_sampled_waveform_repeats_with_period_2n_minus_1_bits(order):
    N = 2**order - 1
    w = prbs(order=order, bit_width=1e-6, sample_rate=1e6, n_samples=3 * N, amplitude=1.0).waveform()
    u = w.u
    np.testing.assert_array_equal(u[:N], u[N : 2 * N])
    np.testing.assert_array_equal(u[:N], u[2 * N :])
    for p in range(1, N):  # no shorter period
        if N % p == 0 or p < 64:
            assert not np.array_equal(u[:N], np.roll(u[:N], p)), p
    assert w.info["period_bits"] == N
    assert w.info["order"] == order


@pytest.mark.parametrize("amplitude", [0.25, 1.0, 7.5])
def test_levels_are_plus_minus_amplitude(amplitude):
    w = prbs(order=9, bit_width=0.4e-6, sample_rate=25e6, amplitude=amplitude).waveform()
    assert set(np.unique(w.u)) == {-amplitude, amplitude}
    # Nearly balanced over a whole period (one more +1 bit than -1 bit).
    assert abs(w.u.mean()) <= amplitude * 2.0 / 511


def test_integer_samples_per_bit():
    """Fig. 3.7 setting 2: 0.4 us bits at 25 MS/s = 10 samples per bit."""
    w = prbs(order=9, bit_width=0.4e-6, sample_rate=25e6, n_samples=5000).waveform()
    np.testing.assert_allclose(w.t, np.arange(5000) / 25e6, rtol=0, atol=1e-18)
    assert w.dt == pytest.approx(40e-9)
    assert w.sample_rate == pytest.approx(25e6)
    expected = np.repeat(2.0 * mls_bits(9) - 1.0, 10)[:5000]
    np.testing.assert_array_equal(w.u, expected)


def test_fractional_samples_per_bit_follow_the_bit_clock():
    """Fig. 3.7 setting 1: 2.5 us bits at 6.25 MS/s = 15.625 samples per bit. Sample k belongs to
    bit floor(k / 15.625) (exact rational arithmetic here); an edge between samples takes effect
    at the next sample."""
    w = prbs(order=9, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=6200).waveform()
    bits = 2.0 * mls_bits(9) - 1.0
    per_bit = Fraction(25, 10) * Fraction(625, 100)  # (2.5e-6 s) * (6.25e6 /s)
    index = [int(Fraction(k) / per_bit) % bits.size for k in range(6200)]
    np.testing.assert_array_equal(w.u, bits[index])
    # A bit edge that falls between samples takes effect at the next sample.
    j = next(j for j in range(1, 511) if bits[j] != bits[j - 1] and (j * per_bit).denominator != 1)
    k = int(np.ceil(float(j * per_bit)))
    assert w.u[k - 1] == bits[j - 1] and w.u[k] == bits[j]


def test_shift_rotates_the_sequence_by_whole_bits():
    a = prbs(order=7, bit_width=1e-6, sample_rate=4e6, n_samples=4 * 127).waveform().u
    b = prbs(order=7, bit_width=1e-6, sample_rate=4e6, n_samples=4 * 127, shift=5).waveform().u
    np.testing.assert_array_equal(b, np.roll(a, -5 * 4))


def test_record_length_options():
    # Default: one full period.
    o = validate_options(PrbsOptions, {"order": 9, "bit_width": 2.5e-6, "sample_rate": 6.25e6}, "excitation.options")
    assert o.n_samples == round(511 * 2.5e-6 * 6.25e6) == 7984
    assert len(Prbs(o).waveform().u) == 7984
    # Duration in seconds.
    w = prbs(order=9, bit_width=0.4e-6, sample_rate=25e6, duration=200e-6).waveform()
    assert len(w.u) == 5000
    # Explicit sample count, longer than a period: the sequence wraps around.
    w = prbs(order=3, bit_width=1e-6, sample_rate=2e6, n_samples=100).waveform()
    assert len(w.u) == len(w.t) == 100
    np.testing.assert_array_equal(w.u[:14], w.u[14:28])


@pytest.mark.parametrize(
    "options, fragment",
    [
        ({"n_samples": 5000, "duration": 1e-3}, "not both"),
        ({"bit_width": 1e-9, "sample_rate": 25e6}, "shorter than one sample"),
        ({"order": 2}, "excitation.options.order"),
        ({"order": 21}, "excitation.options.order"),
        ({"amplitude": 0}, "excitation.options.amplitude"),
        ({"bit_width": -1e-6}, "excitation.options.bit_width"),
        ({"n_samples": 8}, "excitation.options.n_samples"),
        ({"ordr": 9}, "did you mean 'order'"),
    ],
)
def test_bad_options_are_one_line_config_errors(options, fragment):
    with pytest.raises(ConfigError) as info:
        validate_options(PrbsOptions, options, "excitation.options")
    msg = str(info.value)
    assert fragment in msg
    assert "\n" not in msg
    assert msg.startswith("excitation.options")


@pytest.mark.parametrize("bit_width, sample_rate", [(0.4e-6, 25e6), (2.5e-6, 6.25e6), (1e-6, 20e6)])
def test_spectrum_has_sinc_squared_envelope_and_3db_bandwidth(bit_width, sample_rate):
    """-3 dB bandwidth about 0.443 / T_b (Fig. 3.7); nulls at multiples of 1/T_b."""
    ex = prbs(order=10, bit_width=bit_width, sample_rate=sample_rate)
    w = ex.waveform()
    spec = ex.spectrum()
    expected = 0.443 / bit_width
    assert w.info["bandwidth_3db_hz"] == pytest.approx(expected)
    assert spec.bandwidth_3db() == pytest.approx(expected, rel=0.06)
    assert spec.f[-1] == pytest.approx(sample_rate / 2, rel=1e-3)
    # Spectrum of the same samples computed independently.
    ref = np.abs(np.fft.rfft(w.u - w.u.mean())) ** 2
    np.testing.assert_allclose(spec.power / spec.power.max(), ref / ref.max(), rtol=1e-9, atol=1e-12)
    # First null at 1/T_b: more than 20 dB below the low-frequency level.
    low = spec.power[(spec.f > 0) & (spec.f < 0.1 / bit_width)].mean()
    near_null = spec.power[np.abs(spec.f - 1.0 / bit_width) < 0.01 / bit_width].mean()
    assert near_null < low * 1e-2


def test_power_spectrum_of_a_sine():
    dt = 1e-6
    t = np.arange(1000) * dt
    spec = power_spectrum(np.sin(2 * np.pi * 50e3 * t), dt)
    assert spec.f[np.argmax(spec.power)] == pytest.approx(50e3)
    # Parseval: sum of the one-sided periodogram ~ mean square * duration.
    df = spec.f[1] - spec.f[0]
    assert 2 * spec.power.sum() * df == pytest.approx(0.5, rel=0.01)


def test_registered_as_prbs():
    from mbus_framework.interfaces.plugin_manager import new_plugin_manager
    from mbus_framework.interfaces.registry import Registry

    reg = Registry.from_manager(new_plugin_manager())
    assert reg.get("excitation", "prbs").implementation is Prbs


@pytest.mark.parametrize("order", range(2, 17))
def test_own_shift_register_gives_scipys_maximal_length_sequence(order):
    from scipy.signal import max_len_seq

    from mbus_plugins.excitations.prbs import mls_bits

    np.testing.assert_array_equal(mls_bits(order), max_len_seq(order)[0])


@pytest.mark.parametrize("n", [100, 511, 5000, 5111])
def test_input_spectrum_is_scipys_welch(n):
    from scipy.signal import welch

    from mbus_framework.pipeline.recorded_input import welch_spectrum

    u = np.random.default_rng(n).normal(size=n) + 2.0
    got = welch_spectrum(u, 4e-8)
    f, p = welch(u - u.mean(), 1 / 4e-8, nperseg=int(min(n, max(64, n // 8))))
    np.testing.assert_allclose(got.f, f)
    np.testing.assert_allclose(got.power, p, rtol=1e-10)


@pytest.mark.parametrize("n, nperseg", [(1000, 256), (5111, 1277), (300, 300)])
def test_cross_spectral_density_is_scipys_csd(n, nperseg):
    from scipy.signal import csd

    from mbus_framework.engine.welch import cross_spectral_density

    rng = np.random.default_rng(n)
    x, y = rng.normal(size=n) + 1.0, rng.normal(size=n) - 0.5
    f_ref, P_ref = csd(x, y, 1 / 4e-8, nperseg=nperseg)
    f, P = cross_spectral_density(x, y, 4e-8, nperseg)
    np.testing.assert_allclose(f, f_ref)
    np.testing.assert_allclose(P, P_ref, rtol=1e-10, atol=1e-12 * np.max(np.abs(P_ref)))
