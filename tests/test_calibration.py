"""Chapter 5 calibration: G_TR recovered from noisy multi-length water records on the virtual
rig (within 1 dB and 5 degrees across the pair's band, several pairs including mismatched ones),
the corrected eq. 5.4 root, the calibration file, the run, and its config errors."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from mbus_framework.compensation.calibration_file import (
    load_calibration,
    save_calibration,
)
from mbus_framework.compensation.transfer import (
    compare_with_truth,
    estimate_transfer,
    two_length_estimate,
)
from mbus_framework.errors import ConfigError, DataError
from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_framework.interfaces.sample import Sample
from mbus_framework.pipeline.config import validate_options
from mbus_framework.studies.transducer_calibration import run_calibration
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.excitations.sine_sweep import SineSweep, SineSweepOptions
from test_report import assert_folder_report

LENGTHS = [0.0, 0.005, 0.010, 0.015, 0.020, 0.025]
FS = 25e6


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_manager(new_plugin_manager())


def measure(registry, waveform, transducers: dict, lengths=LENGTHS, averages=16, noise=0.03, seed=1, **extra):
    """One noisy record per length (independent noise: seed + j)."""
    cls = registry.get("backend", "simulated").implementation
    records = []
    for j, length in enumerate(lengths):
        opts = {"wave": {}, "transducers": transducers, "scope": {"averages": averages},
                "noise": {"relative_std": noise}, "seed": seed + j, **extra}
        backend = cls(validate_options(cls.Options, opts, "backend.options"))
        m = backend.acquire(AcquisitionContext(waveform, Sample(length, 0.0254, 998.0), None, registry))
        records.append((m.t, m.u, m.y))
    return backend, records


PAIRS = {
    "identical A301S-like": {},
    "mismatched centres": {"mismatch": {"centre_frequency": 0.15}},
    "mismatched bandwidth and gain": {"mismatch": {"bandwidth": -0.3, "gain": 0.4}, "gain": 0.3},
    "third-order, all mismatched": {"order": 3, "mismatch": {"centre_frequency": -0.1, "bandwidth": 0.2, "gain": -0.2}},
    "1 MHz pair": {"centre_frequency": 1.0e6, "bandwidth": 0.6e6, "mismatch": {"centre_frequency": 0.08}},
}


@pytest.mark.parametrize("name", list(PAIRS))
def test_calibration_recovers_the_pair_within_1_db_and_5_degrees(registry, name):
    transducers = PAIRS[name]
    bit = 0.4e-6 if "1 MHz" not in name else 0.2e-6
    w = Prbs(PrbsOptions(order=8, bit_width=bit, sample_rate=FS, periods=3)).waveform()
    backend, records = measure(registry, w, transducers)
    period = int(round(w.info["period_samples"]))
    band = backend.pair.band()
    est = estimate_transfer(records, LENGTHS, "zoh", period, band=band)
    check = compare_with_truth(est.f, est.G_TR, backend.true_transducer_response(est.f), band)
    assert check["n_lines"] > 20
    assert check["max_abs_magnitude_error_db"] < 1.0, check
    assert check["max_abs_phase_error_deg"] < 5.0, check
    # The band is inside the reliable band, and water's sound speed comes out of Im gamma.
    lo, hi = est.reliable_band
    assert lo <= band[0] and hi >= band[1]
    assert est.sound_speed(band) == pytest.approx(1482.0, rel=0.005)
    # Relative delays (the unwrapping aid) are the water paths l / c, to a fraction of a sample.
    np.testing.assert_allclose(est.delays_s, np.array(LENGTHS) / 1482.0, atol=0.5 / FS)


def test_calibration_without_a_zero_length_and_with_transient_analysis(registry):
    """A tapered chirp burst that dies out inside the record: the zero-padded record's Y/U is
    exact (transient analysis). Lengths 5-25 mm only: G_TR is extrapolated to l = 0."""
    o = validate_options(SineSweepOptions, {"f_start": 0.15e6, "f_stop": 1.2e6, "sample_rate": FS, "n_samples": 6000,
                                            "sweep_duration": 100e-6, "taper": 0.1}, "excitation.options")
    w = SineSweep(o).waveform()
    lengths = LENGTHS[1:]
    backend, records = measure(registry, w, {"mismatch": {"gain": 0.2}}, lengths=lengths, averages=64)
    band = backend.pair.band()
    est = estimate_transfer(records, lengths, "zoh", None, band=band)
    check = compare_with_truth(est.f, est.G_TR, backend.true_transducer_response(est.f), band)
    assert check["max_abs_magnitude_error_db"] < 1.0 and check["max_abs_phase_error_deg"] < 5.0, check


def test_the_root_of_eq_5_4_is_the_n_minus_1_th():
    """G_tot(L) = G_TR G_M, G_tot(nL) = G_TR G_M^n: the ratio is G_M^(n-1)."""
    f = np.linspace(0.2e6, 0.8e6, 50)
    log_tr = -0.3 + 0.5j * np.sin(f / 1e5)
    log_m = -0.02 * (f / 1e6) ** 2 - 2j * np.pi * f * 3.4e-6  # 5 mm of water, unwrapped phase
    n = 3
    G_M, G_TR = two_length_estimate(log_tr + log_m, log_tr + n * log_m, n)
    np.testing.assert_allclose(G_M, np.exp(log_m), rtol=1e-12)
    np.testing.assert_allclose(G_TR, np.exp(log_tr), rtol=1e-12)
    printed_root = np.exp(((log_tr + n * log_m) - (log_tr + log_m)) / n)  # eq. 5.4 as printed
    assert np.max(np.abs(printed_root / np.exp(log_m) - 1)) > 0.1
    with pytest.raises(ValueError):
        two_length_estimate(log_tr, log_tr, 1)


def test_two_lengths_give_the_same_answer_as_the_fit(registry):
    w = Prbs(PrbsOptions(order=8, bit_width=0.4e-6, sample_rate=FS, periods=3)).waveform()
    backend, records = measure(registry, w, {}, lengths=[0.005, 0.015], noise=0.0, averages=1, scope=None)
    period = int(round(w.info["period_samples"]))
    est = estimate_transfer(records, [0.005, 0.015], "zoh", period, band=backend.pair.band())
    logs = np.log(est.G_tot[0]), np.log(est.G_tot[1])
    # The fit's logs carry the unwrapped phases; eq. 5.4-5.5 with n = 3 must agree with it.
    log_l = np.log(np.abs(est.G_tot)) + 1j * (est.log_G_TR.imag + np.outer(est.lengths, est.gamma.imag))
    G_M, G_TR = two_length_estimate(log_l[0], log_l[1], 3)
    sel = est.reliable
    np.testing.assert_allclose(G_TR[sel], est.G_TR[sel], rtol=1e-9)
    np.testing.assert_allclose(G_M[sel], np.exp(0.005 * est.gamma[sel]), rtol=1e-9)
    assert np.isnan(est.se_log_magnitude).all()  # two lengths: no residual degrees of freedom
    assert logs[0].shape == est.f.shape


def test_calibration_file_round_trip(tmp_path, registry):
    w = Prbs(PrbsOptions(order=7, bit_width=0.4e-6, sample_rate=FS, periods=3)).waveform()
    backend, records = measure(registry, w, {}, averages=4)
    est = estimate_transfer(records, LENGTHS, "zoh", int(round(w.info["period_samples"])), band=backend.pair.band())
    npz, side = save_calibration(tmp_path / "cal", est, {"pair": "P1", "date": "2024-01-01"})
    assert npz.suffix == ".npz" and side.suffix == ".json"
    for path in (npz, side):
        cal = load_calibration(path)
        assert cal.meta["pair"] == "P1"
        np.testing.assert_array_equal(cal.f, est.f)
    sel = cal.reliable
    np.testing.assert_allclose(cal.response(cal.f[sel]), est.G_TR[sel], rtol=1e-9)
    assert np.all(cal.response(np.array([1e3, 5e6])) == 0)
    ext = cal.response(np.array([0.1e6]), extend=True)
    assert 0 < abs(ext[0]) < 0.1
    with pytest.raises(DataError, match="calibration file not found"):
        load_calibration(tmp_path / "nope.npz")
    side.write_text(json.dumps({"format": "something else"}))
    with pytest.raises(DataError, match="not an mbus calibration"):
        load_calibration(npz)


def write_config(tmp_path: Path, **calibration) -> Path:
    cfg = yaml.safe_load(Path("configs/water_calibration.yaml").read_text())
    cfg["excitation"]["options"].update({"order": 7, "periods": 3})
    cfg["backend"]["options"]["scope"]["averages"] = 16
    cfg["backend"]["options"]["transducers"]["mismatch"] = {"centre_frequency": 0.1, "gain": -0.2}
    cfg["calibration"]["output"] = str(tmp_path / "cals" / "pair.npz")
    cfg["calibration"].update(calibration)
    cfg["output"] = {"directory": str(tmp_path / "runs"), "plots": True}
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_calibration_run_saves_records_file_and_figures(tmp_path):
    cfg = write_config(tmp_path)
    out = tmp_path / "run"
    text = run_calibration(cfg, [], out)
    assert "transducer calibration: virtual A301S pair" in text
    assert "vs the rig's true transducer response" in text
    assert sorted(p.name for p in (out / "records").glob("*.csv")) == [
        f"length_{x:06.3f}mm.csv" for x in (0, 5, 10, 15, 20, 25)
    ]
    assert (out / "fig5_3_gtot.png").stat().st_size > 10_000 and (out / "fig5_4_gtr.png").stat().st_size > 10_000
    assert_folder_report(out, len(list(out.glob("*.png"))), "transducer calibration: virtual A301S pair")
    meta = json.loads((tmp_path / "cals" / "pair.json").read_text())
    assert meta["pair"] == "virtual A301S pair (0.5 MHz, 25.4 mm)" and meta["reference"] == "water"
    assert meta["analysis"] == "periodic" and meta["lengths_m"] == LENGTHS and meta["date"]
    chk = meta["check_against_true_response"]
    assert chk["max_abs_magnitude_error_db"] < 1.0 and chk["max_abs_phase_error_deg"] < 5.0
    cal = load_calibration(tmp_path / "cals" / "pair.npz")
    assert cal.f[1] - cal.f[0] == pytest.approx(FS / (127 * 10))
    assert (out / "calibration.npz").is_file()
    rec = json.loads((out / "records" / "length_05.000mm.json").read_text())
    assert rec["meta"]["seed"] == 12  # seed + index: independent noise per length


def test_records_are_on_disk_before_anything_is_estimated(tmp_path, monkeypatch):
    import mbus_framework.studies.transducer_calibration as calmod

    def boom(*a, **k):
        raise RuntimeError("estimation crashed")

    monkeypatch.setattr(calmod, "estimate_transfer", boom)
    out = tmp_path / "run"
    with pytest.raises(RuntimeError, match="estimation crashed"):
        run_calibration(write_config(tmp_path), [], out)
    assert len(list((out / "records").glob("*.csv"))) == 6


@pytest.mark.parametrize(
    "override, fragment",
    [
        ("calibration.lenghts=[0, 0.01]", "calibration.lenghts: unknown key; did you mean 'lengths'"),
        ("calibration.lengths=[0.01]", "calibration: lengths: give at least two lengths"),
        ("calibration.lengths=[-0.01, 0.01]", "calibration: lengths: must be >= 0"),
        ("calibration.band=[0.7e6, 0.3e6]", "calibration: band: expected [f_lo, f_hi]"),
        ("calibration.analysis=fourier", "calibration.analysis: Input should be"),
        ("excitation.options.periods=1", "calibration.analysis: periodic needs"),
    ],
)
def test_config_errors_are_one_line_and_name_the_key(tmp_path, override, fragment):
    overrides = [override] + (["calibration.analysis=periodic"] if "periods=1" in override else [])
    with pytest.raises(ConfigError) as info:
        run_calibration(write_config(tmp_path), overrides, tmp_path / "run")
    msg = str(info.value)
    assert fragment in msg and "\n" not in msg and msg.startswith(str(tmp_path / "cal.yaml"))


def test_simulated_calibration_needs_a_reference_path(tmp_path):
    with pytest.raises(ConfigError, match="needs backend.options.wave"):
        run_calibration(write_config(tmp_path), ["backend.options.wave=null", "backend.options.truth={k_sigma: 1}"],
                        tmp_path / "run")
