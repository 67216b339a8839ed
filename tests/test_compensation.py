"""``transfer_function`` compensation (Chapter 5) on the virtual rig: the potato through the
virtual A301S-like pair is biased without compensation; with the water calibration both modes
bring the estimates within 3 standard errors of the truth, and ``forward`` has the smaller
standard errors. Standard errors are the sandwich form for the compensated (coloured) noise."""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.compensation.calibration_file import load_calibration
from mbus_framework.compensation.filters import SpectralFilter
from mbus_framework.errors import ConfigError, DataError
from mbus_framework.interfaces.backend import Measurement
from mbus_framework.pipeline.config import load_config, validate_options
from mbus_framework.pipeline.run import build_components, execute
from mbus_framework.studies.transducer_calibration import run_calibration
from mbus_plugins.compensators.transfer_function import (
    TransferFunctionCompensator,
    TransferFunctionOptions,
    band_window,
    coloured_noise_standard_errors,
)

POTATO = "configs/potato_compensated.yaml"
TRUTH = "{E_sigma: 2.42e10, eta_sigma: 7.18e3, E_tau: 6.56e9, eta_tau: 5.14e3}"


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    """The water calibration of configs/water_calibration.yaml, written to a temporary file."""
    tmp = tmp_path_factory.mktemp("cal")
    run_calibration("configs/water_calibration.yaml", [f"calibration.output={tmp / 'pair.npz'}", "output.plots=false"],
                    tmp / "run")
    return tmp / "pair.npz"


def fit(calibration, tmp_path, *overrides):
    out = execute(POTATO, [f"compensator.options.calibration={calibration}", *overrides], tmp_path, plots=False)
    comp = out.components.compensator
    names = [n for n, f in zip(out.fit.names, out.fit.free) if f]
    noise_filter = comp.noise_filter() if hasattr(comp, "noise_filter") else None
    se = coloured_noise_standard_errors(out.fit.jacobian, out.measurement.meta["noise_std"], noise_filter,
                                        out.measurement.dt)
    truth = out.result["truth"]
    est = out.result["parameters"]
    z = {n: (est[n] - truth[n]) / s for n, s in zip(names, se)}
    rse = {n: s / truth[n] for n, s in zip(names, se)}
    return out, z, rse


@pytest.fixture(scope="module")
def both_modes(calibration, tmp_path_factory):
    return {mode: fit(calibration, tmp_path_factory.mktemp(mode), f"compensator.options.mode={mode}")
            for mode in ("forward", "deconvolve")}


@pytest.mark.parametrize("mode", ["forward", "deconvolve"])
def test_compensated_estimates_are_within_3_standard_errors(both_modes, mode):
    out, z, rse = both_modes[mode]
    assert out.fit.success
    assert max(abs(v) for v in z.values()) < 3.0, (z, out.result["error_percent"])
    assert out.result["fit"]["nrmse"] < 0.05
    assert out.components.compensator.last_info["mode"] == mode


@pytest.mark.parametrize("mode", ["forward", "deconvolve"])
def test_the_compensated_potato_is_accepted_without_a_warning(both_modes, mode):
    """Issue 28: the compensation is not exact, so on this 5000-sample record a little
    input-related residual is significant (p ~ 1e-9) while every estimate is within 3 SE; it is
    below the strategy's min_excess, so the first start is accepted and nothing warns."""
    out, _, _ = both_modes[mode]
    strategy = out.result["strategy"]
    assert strategy["accepted"] and len(strategy["starts"]) == 1, strategy.get("accepted_because")
    assert out.result["warnings"] == []


def test_forward_has_smaller_standard_errors_than_deconvolve(both_modes):
    _, _, forward = both_modes["forward"]
    _, _, deconv = both_modes["deconvolve"]
    for name in forward:
        assert forward[name] < deconv[name], (forward, deconv)


def test_without_compensation_the_estimates_are_biased(calibration, tmp_path):
    """Fitted from the truth itself (a local Levenberg-Marquardt fit, no global search: the full
    strategy is in the slow test), the uncompensated fit leaves the truth by tens of percent."""
    out = execute(POTATO, [
        "compensator.name=none", "compensator.options={}", f"model.initial={TRUTH}",
        "solver.options.strategy.n_starts=1", "solver.options.strategy.bands=[]",
        "solver.options.strategy.coordinate_scan=0", "solver.options.strategy.time_scale=false",
    ], tmp_path, plots=False)
    err = out.result["error_percent"]
    assert max(abs(v) for v in err.values()) > 20.0, err
    se = out.result["uncertainty"]["standard_errors"]
    z = {n: (out.result["parameters"][n] - out.result["truth"][n]) / se[n] for n in se}
    assert max(abs(v) for v in z.values()) > 30.0


@pytest.mark.slow
def test_uncompensated_bias_with_the_full_strategy(tmp_path):
    out = execute(POTATO, ["compensator.name=none", "compensator.options={}"], tmp_path, plots=False)
    err = out.result["error_percent"]
    assert abs(err["b_sigma"]) > 20 and abs(err["k_tau"]) > 100, err


@pytest.mark.slow
def test_sandwich_standard_errors_match_the_spread_over_noise_seeds(calibration, tmp_path):
    """12 noise realisations of the forward-compensated fit: the sample std of each estimate is
    within a factor 1.6 of the sandwich SE (chi-square with 11 dof: 95 % range 0.6-1.4)."""
    estimates, ses = [], []
    for seed in range(12):
        out, _, rse = fit(calibration, tmp_path / str(seed), "compensator.options.mode=forward",
                          f"backend.options.seed={100 + seed}")
        estimates.append([out.result["parameters"][n] / out.result["truth"][n] for n in rse])
        ses.append(list(rse.values()))
    ratio = np.std(estimates, axis=0, ddof=1) / np.mean(ses, axis=0)
    assert np.all((ratio > 1 / 1.6) & (ratio < 1.6)), ratio


def test_deconvolution_estimates_the_noise_out_of_band(both_modes):
    out, _, _ = both_modes["deconvolve"]
    info = out.components.compensator.last_info
    assert info["noise_std_source"] == "estimated out of band"
    assert info["noise_std"] == pytest.approx(out.measurement.meta["noise_std"], rel=0.25)
    assert 0 < info["wiener_mean_gain_in_band"] <= 1


def test_spectral_filters_are_linear_and_their_adjoint_is_the_transpose():
    rng = np.random.default_rng(0)
    dt = 1e-7
    filt = SpectralFilter(lambda f: np.exp(-2j * np.pi * f * 3e-6) / (1 + 1j * f / 2e5))
    x, y = rng.normal(size=300), rng.normal(size=300)
    assert np.dot(filt(x, dt), y) == pytest.approx(np.dot(x, filt.adjoint(y, dt)), rel=1e-10)
    X = rng.normal(size=(300, 3))
    np.testing.assert_allclose(filt(X, dt)[:, 1], filt(X[:, 1], dt), atol=1e-12)
    np.testing.assert_allclose(filt(2 * x + y, dt), 2 * filt(x, dt) + filt(y, dt), atol=1e-12)
    # A pure delay of 30 samples, causal and linear (not circular): the tail drops off.
    delay = SpectralFilter(lambda f: np.exp(-2j * np.pi * f * 30 * dt))
    np.testing.assert_allclose(delay(x, dt)[30:], x[:-30], atol=1e-10)
    np.testing.assert_allclose(delay(x, dt)[:30], 0, atol=1e-10)


def test_band_window_shape():
    f = np.linspace(0, 2e6, 2001)
    P = band_window(f, (0.2e6, 1.2e6), 0.1)
    assert np.all(P[(f < 0.2e6) | (f > 1.2e6)] == 0)
    assert np.all(P[(f >= 0.3e6) & (f <= 1.1e6)] == 1)
    ramp = (f > 0.2e6) & (f < 0.3e6)
    assert np.all(np.diff(P[ramp]) > 0) and P[np.argmin(np.abs(f - 0.25e6))] == pytest.approx(0.5)


def compensator(calibration, **options):
    o = validate_options(TransferFunctionOptions, {"calibration": str(calibration), **options}, "compensator.options")
    return TransferFunctionCompensator(o)


def test_forward_mode_models_g_tr_inside_the_reliable_band(calibration):
    comp = compensator(calibration)
    cal = load_calibration(calibration)
    lo, hi = cal.reliable_band
    assert comp.band == (lo, hi)
    f = cal.f[cal.reliable]
    np.testing.assert_allclose(comp.transducer_response(f), cal.G_TR[cal.reliable], rtol=1e-9)
    narrow = compensator(calibration, band=[0.3e6, 0.7e6])
    assert narrow.band == (0.3e6, 0.7e6)
    m = Measurement(np.arange(4000) * 4e-8, np.ones(4000), np.random.default_rng(1).normal(size=4000))
    out = narrow.apply(m)
    Y = np.abs(np.fft.rfft(out.y))
    fr = np.fft.rfftfreq(4000, 4e-8)
    assert Y[(fr > 1.5e6)].max() < 0.05 * Y[(fr > 0.35e6) & (fr < 0.65e6)].mean()  # band-limited, not divided
    assert narrow.noise_filter() is narrow._window


def test_tikhonov_deconvolution(calibration):
    comp = compensator(calibration, mode="deconvolve", regularisation="tikhonov", weight=1e-3, noise_std=1e-3)
    rng = np.random.default_rng(2)
    m = Measurement(np.arange(4000) * 4e-8, np.ones(4000), rng.normal(scale=1e-3, size=4000))
    with pytest.raises(RuntimeError, match="call apply"):
        comp.output_filter()
    out = comp.apply(m)
    info = out.meta["compensation"]
    assert info["tikhonov_lambda_relative"] == pytest.approx(1e-3)
    # |W| <= 1 / (2 sqrt(lambda)) and the model's band limit B = W G lies in [0, 1].
    assert info["noise_gain_max"] <= 1 / (2 * np.sqrt(info["tikhonov_lambda"])) * 1.0001
    f = np.fft.rfftfreq(8000, 4e-8)
    B = comp._deconvolution.response(f) * comp._transducers.response(f)
    assert np.all(B.real >= -1e-12) and np.all(B.real <= 1 + 1e-12) and np.max(np.abs(B.imag)) < 1e-9


def test_errors_and_pair_mismatch_warning(calibration, tmp_path):
    with pytest.raises(DataError, match="nope.npz: calibration file not found"):
        build_components(load_config(POTATO, [f"compensator.options.calibration={tmp_path / 'nope.npz'}"]), POTATO)
    with pytest.raises(ConfigError, match="does not overlap"):
        compensator(calibration, band=[5e6, 6e6])
    with pytest.raises(ConfigError, match="compensator.options.mode"):
        validate_options(TransferFunctionOptions, {"calibration": "x", "mode": "divide"}, "compensator.options")
    comp = compensator(calibration)
    m = Measurement(np.arange(100) * 4e-8, np.ones(100), np.zeros(100), meta={"transducers": {"name": "another pair"}})
    assert "is not the calibrated" in comp.apply(m).meta["compensation"]["warning"]


def test_cli_exit_code_for_a_missing_calibration(tmp_path):
    from mbus_framework.cli import main

    code = main([POTATO, "--set", f"compensator.options.calibration={tmp_path / 'missing.npz'}", "-q"])
    assert code == 2
