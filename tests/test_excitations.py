"""Excitations against analytic values: PRBS line spectrum on the sinc^2 envelope and inverse
repeat, chirp instantaneous frequency, multisine grid, file waveforms, crest factors, and the
generator quantisation (DS340: 12-bit codes within +-2047 on a clock/N point-rate grid)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import hilbert

from mbus_framework.pipeline.config import validate_options
from mbus_framework.errors import ConfigError, DataError
from mbus_framework.interfaces.excitation import QuantizeOptions, Waveform, crest_factor, power_spectrum, quantize_waveform
from mbus_plugins.excitations.from_file import FromFile, FromFileOptions
from mbus_plugins.excitations.multisine import Multisine, MultisineOptions
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions, mls_bits
from mbus_plugins.excitations.sine_sweep import SineSweep, SineSweepOptions


def make(cls, **options):
    return cls(validate_options(cls.Options, options, "excitation.options"))


# -- PRBS ------------------------------------------------------------------------------------
@pytest.mark.parametrize("order, per_bit", [(7, 4), (9, 10), (10, 3)])
def test_prbs_line_spectrum_follows_the_sinc_squared_envelope(order, per_bit):
    """One period of an m-sequence: every line k/(P T_b), k not a multiple of P, has the same
    power before pulse shaping; holding each bit for m samples multiplies it by the sampled
    sinc^2, |sin(pi f T_b) / (m sin(pi f dt))|^2, which tends to sinc^2(f T_b)."""
    fs = 1e6 * per_bit
    tb = per_bit / fs
    P = 2**order - 1
    w = make(Prbs, order=order, bit_width=tb, sample_rate=fs, periods=1).waveform()
    assert len(w.u) == P * per_bit
    U = np.fft.rfft(w.u)
    f = np.fft.rfftfreq(len(w.u), 1 / fs)
    k = np.arange(len(f))
    lines = (k > 0) & (k % P != 0)
    envelope = np.zeros_like(f)
    x = np.pi * f[1:] / fs
    envelope[1:] = np.abs(np.sin(np.pi * f[1:] * tb) / (per_bit * np.sin(x))) ** 2
    ratio = np.abs(U[lines]) ** 2 / envelope[lines]
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)
    # m-sequence line power: (P + 1) per_bit^2 A^2 at every line; DC: (per_bit A)^2.
    assert ratio[0] == pytest.approx((P + 1) * per_bit**2, rel=1e-9)
    assert abs(U[0]) == pytest.approx(per_bit, rel=1e-9)
    # The sampled envelope is the continuous sinc^2(f T_b) times (x / sin x)^2, x = pi f / f_s
    # (the sample-rate correction, -> 1 for many samples per bit).
    xs = np.pi * f[lines] / fs
    np.testing.assert_allclose(envelope[lines] * (np.sin(xs) / xs) ** 2, np.sinc(f[lines] * tb) ** 2, rtol=1e-9, atol=1e-15)
    # -3 dB bandwidth near 0.443 / T_b (exact for the continuous envelope; sampled: within 6 %).
    spec = power_spectrum(w.u, 1 / fs)
    assert spec.bandwidth_3db() == pytest.approx(0.443 / tb, rel=0.06)
    assert w.info["line_spacing_hz"] == pytest.approx(1 / (P * tb))
    assert w.info["period_samples"] == pytest.approx(P * per_bit)


def test_prbs_inverse_repeat_cancels_the_even_lines():
    per_bit, order = 4, 7
    fs = 4e6
    w = make(Prbs, order=order, bit_width=per_bit / fs, sample_rate=fs, inverse_repeat=True, periods=2).waveform()
    P2 = 2 * (2**order - 1) * per_bit
    assert len(w.u) == 2 * P2
    np.testing.assert_array_equal(w.u[:P2], w.u[P2:])
    half = P2 // 2
    np.testing.assert_array_equal(w.u[half:P2], -w.u[:half])
    U = np.abs(np.fft.rfft(w.u[:P2]))
    assert np.max(U[0::2]) < 1e-9 * np.max(U)  # even multiples of 1/(2 P T_b) vanish (DC too)
    assert np.all(U[1::2][: 2**order // 2] > 1e-3 * np.max(U))
    assert w.info["inverse_repeat"] is True


def test_prbs_periods_and_the_old_defaults():
    o = validate_options(PrbsOptions, {"order": 9, "bit_width": 2.5e-6, "sample_rate": 6.25e6}, "excitation.options")
    assert o.n_samples == 7984  # one period, as before
    w = make(Prbs, order=5, bit_width=1e-6, sample_rate=3e6, periods=3).waveform()
    assert len(w.u) == 3 * 31 * 3
    np.testing.assert_array_equal(w.u[:93], w.u[93:186])
    assert w.info["periods"] == pytest.approx(3.0)
    with pytest.raises(ConfigError, match="give one of n_samples, duration or periods"):
        validate_options(PrbsOptions, {"periods": 2, "n_samples": 100}, "excitation.options")


# -- sine sweep ------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["linear", "log"])
def test_chirp_instantaneous_frequency_matches_the_analytic_law(kind):
    fs, n = 25e6, 5000
    ex = make(SineSweep, kind=kind, f_start=0.3e6, f_stop=0.7e6, sample_rate=fs, n_samples=n)
    w = ex.waveform()
    phase = np.unwrap(np.angle(hilbert(w.u)))
    f_inst = np.gradient(phase, 1 / fs) / (2 * np.pi)
    t = w.t
    core = slice(n // 10, 9 * n // 10)  # away from the Hilbert transform's edge effects
    T = n / fs
    expected = 0.3e6 + 0.4e6 * t / T if kind == "linear" else 0.3e6 * (0.7 / 0.3) ** (t / T)
    np.testing.assert_allclose(ex.instantaneous_frequency(t), expected, rtol=1e-12)
    np.testing.assert_allclose(f_inst[core], expected[core], rtol=0.02)  # Hilbert: an independent, rougher look
    # The closed-form phase has that derivative.
    np.testing.assert_allclose(np.gradient(ex.phase(t), t)[core] / (2 * np.pi), expected[core], rtol=1e-4)
    assert crest_factor(w.u) == pytest.approx(np.sqrt(2), rel=0.01)
    lo, hi = ex.spectrum().band_3db()
    assert lo == pytest.approx(0.3e6, abs=25e3)
    if kind == "linear":  # flat; a log sweep's density falls as 1/f (-3.7 dB at 0.7 vs 0.3 MHz)
        assert hi == pytest.approx(0.7e6, abs=25e3)
    else:
        assert hi == pytest.approx(0.3e6 / 0.5, rel=0.1)


def test_linear_chirp_spectrum_is_flat_in_its_band_and_the_taper_softens_it():
    fs, n = 25e6, 10000
    plain = make(SineSweep, f_start=0.3e6, f_stop=0.7e6, sample_rate=fs, n_samples=n)
    spec = plain.spectrum()
    inside = (spec.f > 0.35e6) & (spec.f < 0.65e6)
    db = 10 * np.log10(spec.power[inside] / spec.power[inside].mean())
    assert np.max(np.abs(db)) < 2.0  # flat within the Fresnel ripple
    assert spec.power[spec.f > 1.0e6].max() < 1e-3 * spec.power.max()
    tapered = make(SineSweep, f_start=0.3e6, f_stop=0.7e6, sample_rate=fs, n_samples=n, taper=0.2).waveform()
    assert abs(tapered.u[0]) < 1e-12 and np.max(np.abs(tapered.u[-5:])) < 0.01
    assert tapered.info["taper"] == 0.2


def test_sweep_shorter_than_the_record_is_followed_by_rest():
    w = make(SineSweep, f_start=0.2e6, f_stop=0.6e6, sample_rate=10e6, n_samples=2000, sweep_duration=100e-6).waveform()
    assert np.all(w.u[1000:] == 0) and np.max(np.abs(w.u[:1000])) > 0.99


@pytest.mark.parametrize(
    "options, fragment",
    [
        ({"f_stop": 13e6}, "Nyquist"),
        ({"kind": "log", "f_start": 0.0}, "logarithmic sweep needs"),
        ({"f_start": 0.5e6, "f_stop": 0.5e6}, "must differ"),
        ({"taper": 1.5}, "excitation.options.taper"),
        ({"knd": "log"}, "did you mean 'kind'"),
    ],
)
def test_sweep_option_errors(options, fragment):
    with pytest.raises(ConfigError, match=fragment):
        validate_options(SineSweepOptions, options, "excitation.options")


# -- multisine -------------------------------------------------------------------------------
def test_multisine_puts_equal_power_on_its_grid_only():
    fs, n = 25e6, 5000
    ex = make(Multisine, f_min=0.3e6, f_max=0.7e6, sample_rate=fs, n_samples=n, amplitude=2.0)
    w = ex.waveform()
    U = np.abs(np.fft.rfft(w.u))
    f = np.fft.rfftfreq(n, 1 / fs)
    grid = np.arange(60, 141)  # 0.3-0.7 MHz in 5 kHz steps
    np.testing.assert_array_equal(ex.multiples, grid)
    on = np.zeros(U.size, bool)
    on[grid] = True
    np.testing.assert_allclose(U[on], U[on][0], rtol=1e-9)
    assert np.max(U[~on]) < 1e-9 * U[on][0]
    np.testing.assert_allclose(f[on][[0, -1]], [0.3e6, 0.7e6])
    assert np.max(np.abs(w.u)) == pytest.approx(2.0)
    assert w.info["n_lines"] == 81 and w.info["line_spacing_hz"] == pytest.approx(5e3)


def test_multisine_grid_options_and_crest_factors():
    base = {"sample_rate": 10e6, "n_samples": 4000, "f_min": 0.1e6, "f_max": 0.5e6}
    odd = make(Multisine, **base, harmonics="odd")
    assert np.all(odd.multiples % 2 == 1)
    stepped = make(Multisine, **base, step=4)
    assert np.all(np.diff(stepped.multiples) == 4)
    explicit = make(Multisine, sample_rate=10e6, n_samples=4000, frequencies=[0.1e6, 0.25e6, 0.4e6])
    np.testing.assert_array_equal(explicit.multiples, [40, 100, 160])
    # Two periods repeat exactly; the grid is then in steps of 1/(period).
    two = make(Multisine, **base, periods=2).waveform()
    np.testing.assert_allclose(two.u[:2000], two.u[2000:], atol=1e-12)
    schroeder = crest_factor(make(Multisine, **base).waveform().u)
    zero = crest_factor(make(Multisine, **base, phases="zero").waveform().u)
    K = make(Multisine, **base).multiples.size
    assert zero == pytest.approx(np.sqrt(2 * K), rel=1e-6)  # all cosines peak together
    assert 1.3 < schroeder < 2.2 < zero


@pytest.mark.parametrize(
    "options, fragment",
    [
        ({"frequencies": [0.1234e6]}, "not a positive multiple"),
        ({"n_samples": 5001, "periods": 2}, "not divisible"),
        ({"f_min": 0.71e6, "f_max": 0.709e6}, "f_min must not exceed f_max"),
        ({"f_max": 20e6}, "Nyquist"),
    ],
)
def test_multisine_option_errors(options, fragment):
    with pytest.raises(ConfigError, match=fragment):
        validate_options(MultisineOptions, options, "excitation.options")


# -- from file -------------------------------------------------------------------------------
def test_from_file_csv_with_time_column_is_held_point_by_point(tmp_path):
    pts = np.array([0.0, 1.0, -2.0, 0.5, 3.0, -1.0, 2.5, 0.25])
    path = tmp_path / "wave.csv"
    path.write_text("t,u\n" + "\n".join(f"{k * 1e-6},{v}" for k, v in enumerate(pts)))
    w = make(FromFile, path=str(path), sample_rate=4e6).waveform()  # 4 samples per point
    np.testing.assert_array_equal(w.u, np.repeat(pts, 4))
    assert w.info["point_rate_hz"] == pytest.approx(1e6)
    looped = make(FromFile, path=str(path), periods=2, amplitude=1.5).waveform()
    np.testing.assert_allclose(looped.u, np.tile(pts, 2) * 0.5)
    padded = make(FromFile, path=str(path), n_samples=20).waveform()
    np.testing.assert_array_equal(padded.u[8:], 0.0)


def test_from_file_npy_and_npz(tmp_path):
    u = np.sin(np.linspace(0, 6, 50))
    np.save(tmp_path / "a.npy", u)
    w = make(FromFile, path=str(tmp_path / "a.npy"), file_sample_rate=2e6).waveform()
    np.testing.assert_array_equal(w.u, u)
    assert w.dt == pytest.approx(0.5e-6)
    np.savez(tmp_path / "b.npz", u=u, t=np.arange(50) * 1e-7)
    assert make(FromFile, path=str(tmp_path / "b.npz")).waveform().sample_rate == pytest.approx(1e7)


def test_from_file_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match="missing.csv: waveform file not found"):
        make(FromFile, path=str(tmp_path / "missing.csv"))
    np.save(tmp_path / "a.npy", np.ones(40))
    with pytest.raises(DataError, match="file_sample_rate"):
        make(FromFile, path=str(tmp_path / "a.npy"))
    bad = tmp_path / "bad.csv"
    bad.write_text("t,u\n0,1\n1e-6,2\n3e-6,3\n")
    with pytest.raises(DataError, match="bad.csv: time column is not uniform"):
        make(FromFile, path=str(bad))
    col = tmp_path / "c.csv"
    col.write_text("t,v\n0,1\n1e-6,2\n")
    with pytest.raises(DataError, match="no column 'u'"):
        make(FromFile, path=str(col), column="u")


# -- quantisation ----------------------------------------------------------------------------
def test_ds340_codes_are_integers_within_2047():
    ex = make(SineSweep, f_start=0.3e6, f_stop=0.7e6, sample_rate=25e6, n_samples=3000, amplitude=0.8,
              quantize={"bits": 12})
    w = ex.waveform()
    q = w.info["quantize"]
    assert q["max_code"] == 2047
    step = 0.8 / 2047  # full scale = the ideal peak (0.8 up to the sampled maximum)
    assert q["step"] == pytest.approx(step, rel=1e-3)
    codes = w.u / q["step"]
    np.testing.assert_allclose(codes, np.round(codes), atol=1e-9)
    assert np.max(np.abs(np.round(codes))) == 2047
    ideal = ex.signal(w.t)
    assert np.max(np.abs(w.u - ideal)) <= q["step"] / 2 + 1e-15  # point rate = sample rate
    assert q["rms_error"] == pytest.approx(q["step"] / np.sqrt(12), rel=0.1)


def test_point_rate_is_rounded_to_the_clock_grid_and_held():
    ex = make(Multisine, f_min=0.3e6, f_max=0.7e6, sample_rate=25e6, n_samples=5000,
              quantize={"bits": 12, "clock": 40e6, "rate": 7e6})
    w = ex.waveform()
    q = w.info["quantize"]
    assert q["clock_divider"] == 6 and q["point_rate_hz"] == pytest.approx(40e6 / 6)
    # Each generator point is held: u is constant between point instants j / r.
    idx = np.floor(w.t * q["point_rate_hz"] + 1e-9).astype(int)
    for j in np.unique(idx)[:200]:
        assert np.ptp(w.u[idx == j]) == 0.0
    with pytest.raises(ConfigError, match="needs more than 8 bits"):
        validate_options(QuantizeOptions, {"bits": 8, "max_code": 2047}, "excitation.options.quantize")


def test_quantising_a_prbs_keeps_it_exact_and_full_scale_can_clip():
    w = make(Prbs, order=7, bit_width=0.4e-6, sample_rate=25e6, quantize={"bits": 12, "clock": 40e6}).waveform()
    plain = make(Prbs, order=7, bit_width=0.4e-6, sample_rate=25e6).waveform()
    np.testing.assert_array_equal(w.u, plain.u)  # +-2047 codes, edges on the 20 MHz grid (8 points a bit)
    u = np.linspace(-1, 1, 101)
    clipped = quantize_waveform(Waveform(np.arange(101) * 1e-6, u), QuantizeOptions(bits=4, full_scale=0.51))
    assert clipped.info["quantize"]["clipped_points"] == 50
    assert np.max(np.abs(clipped.u)) == pytest.approx(0.51)
    assert set(np.round(clipped.u / (0.51 / 7), 9)) <= set(range(-7, 8))


def test_crest_factors_and_registration():
    from mbus_framework.interfaces.plugin_manager import new_plugin_manager
    from mbus_framework.interfaces.registry import Registry

    assert make(Prbs, order=7, bit_width=1e-6, sample_rate=4e6).crest_factor() == pytest.approx(1.0)
    t = np.arange(1000) / 1e6
    assert crest_factor(np.sin(2 * np.pi * 10e3 * t)) == pytest.approx(np.sqrt(2), rel=1e-3)
    reg = Registry.from_manager(new_plugin_manager())
    for name, cls in [("prbs", Prbs), ("sine_sweep", SineSweep), ("multisine", Multisine), ("from_file", FromFile)]:
        assert reg.get("excitation", name).implementation is cls
    assert "quantize" in FromFileOptions.model_fields and "quantize" in PrbsOptions.model_fields


def test_prbs_bits_reused():
    assert mls_bits(3).size == 7
