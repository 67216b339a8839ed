"""Cyclic compression records -> k, b, E, eta (eqs. 6.14-6.23), against known truth."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mbus_framework.analysis.conventional.compression import (analyse_compression, analyse_compression_file,
                                                              fit_sinusoid)
from mbus_framework.analysis.conventional.synthetic import compression_record, write_compression_csv
from mbus_framework.errors import DataError

LENGTH, AREA = 0.03, math.pi * 0.01 ** 2  # the dissertation's 20 mm x 30 mm specimen


def _truth(k: float, phase_deg: float, frequency: float) -> tuple[float, float]:
    """(k, b) with the force leading the displacement by ``phase_deg`` (eq. 6.21)."""
    return k, k * math.tan(math.radians(phase_deg)) / (2 * math.pi * frequency)


def _analyse(rec, frequency, **kw):
    return analyse_compression(rec["time"], rec["force"], rec["displacement"], frequency=frequency,
                               length=LENGTH, area=AREA, **kw)


@settings(max_examples=40)
@given(k=st.floats(1e3, 1e6), phase_deg=st.floats(0.5, 80.0), frequency=st.floats(0.5, 20.0),
       start=st.floats(0, 2 * math.pi), creep=st.floats(-1e-5, 1e-5), relaxation=st.floats(-0.5, 0.5))
def test_noise_free_records_give_k_and_b_to_1e_6(k, phase_deg, frequency, start, creep, relaxation):
    k, b = _truth(k, phase_deg, frequency)
    rec = compression_record(k, b, frequency=frequency, cycles=3, phase=start, preload=2.0, offset=1e-3,
                             creep=creep, relaxation=relaxation)
    res = _analyse(rec, frequency)
    assert res.k == pytest.approx(k, rel=1e-6)
    assert res.b == pytest.approx(b, rel=1e-6)
    # eqs. 6.20-6.23: gain, phase and the geometry factor l / A
    omega = 2 * math.pi * frequency
    assert res.gain == pytest.approx(1 / math.hypot(omega * b, k), rel=1e-6)
    assert res.phase == pytest.approx(math.atan(omega * b / k), rel=1e-6)
    assert res.E == pytest.approx(LENGTH / AREA * k, rel=1e-6)
    assert res.eta == pytest.approx(LENGTH / AREA * b, rel=1e-6)


@settings(max_examples=30)
@given(k=st.floats(1e3, 1e6), phase_deg=st.floats(2.0, 70.0), frequency=st.sampled_from([0.5, 1.0, 2.0, 5.0]),
       noise=st.floats(0.001, 0.03), seed=st.integers(0, 2 ** 32 - 1))
def test_noisy_records_give_k_and_b_within_their_standard_errors(k, phase_deg, frequency, noise, seed):
    k, b = _truth(k, phase_deg, frequency)
    amplitude = 0.2e-3
    force_amp = amplitude * math.hypot(k, 2 * math.pi * frequency * b)
    rec = compression_record(k, b, frequency=frequency, amplitude=amplitude, cycles=4, creep=1e-6,
                             force_noise=noise * force_amp, displacement_noise=noise * amplitude / 3,
                             rng=np.random.default_rng(seed))
    res = _analyse(rec, frequency)
    assert res.k_se > 0 and res.b_se > 0
    # 5 standard errors: a failure here is a wrong estimate or a wrong SE, not bad luck (p < 1e-6)
    assert abs(res.k - k) < 5 * res.k_se
    assert abs(res.b - b) < 5 * res.b_se
    assert res.E_se == pytest.approx(LENGTH / AREA * res.k_se)


def test_standard_errors_match_the_scatter_over_many_records():
    """z = (estimate - truth) / SE over 300 records: mean 0 and SD 1 (delta method is calibrated)."""
    rng = np.random.default_rng(11)
    k, b = _truth(2.8e4, 6.0, 1.0)
    amp = 0.2e-3 * math.hypot(k, 2 * math.pi * b)
    z = []
    for _ in range(300):
        rec = compression_record(k, b, cycles=4, phase=rng.uniform(0, 2 * math.pi), preload=1.0, creep=2e-6,
                                 force_noise=0.01 * amp, displacement_noise=0.5e-6, rng=rng)
        res = _analyse(rec, 1.0)
        z.append(((res.k - k) / res.k_se, (res.b - b) / res.b_se))
    z = np.array(z)
    assert np.all(np.abs(z.mean(axis=0)) < 0.2)  # SE of a mean of 300 unit normals: 0.058
    assert np.all(np.abs(z.std(axis=0) - 1) < 0.12)
    inside = (np.abs(z) < 1).mean(axis=0)  # 68.3 % expected; binomial SD 2.7 %
    assert np.all(np.abs(inside - 0.683) < 0.09)


def test_sinusoid_fit_standard_errors_are_statsmodels_ols():
    import statsmodels.api as sm

    rng = np.random.default_rng(3)
    t = np.arange(800) / 400.0
    y = 0.3 + 0.1 * t + 2.0 * np.cos(2 * np.pi * t) - 0.7 * np.sin(2 * np.pi * t) + 0.05 * rng.standard_normal(t.size)
    fit = fit_sinusoid(t, y, 2 * np.pi, drift_degree=1)
    X = np.column_stack([np.ones_like(t), t, np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)])
    ref = sm.OLS(y, X).fit()
    assert fit.a == pytest.approx(ref.params[2]) and fit.c == pytest.approx(ref.params[3])
    np.testing.assert_allclose(fit.cov, np.asarray(ref.cov_params())[2:, 2:], rtol=1e-8)
    assert fit.amplitude == pytest.approx(math.hypot(ref.params[2], ref.params[3]))


def test_file_units_are_converted(tmp_path):
    """The same record in g, mm and ms gives the same k and b as in SI."""
    k, b = _truth(3e4, 8.0, 1.0)
    rec = compression_record(k, b, cycles=3, preload=1.0)
    si = write_compression_csv(tmp_path / "si.csv", rec)
    pd.DataFrame({"Time (ms)": rec["time"] * 1e3, "Force (g)": rec["force"] / 9.80665e-3,
                  "Distance (mm)": rec["displacement"] * 1e3}).to_csv(tmp_path / "ta.txt", sep="\t", index=False)
    a = analyse_compression_file(si, frequency=1.0, length=LENGTH, area=AREA)
    c = analyse_compression_file(tmp_path / "ta.txt", frequency=1.0, length=LENGTH, area=AREA)
    assert a.k == pytest.approx(k, rel=1e-5) and c.k == pytest.approx(a.k, rel=1e-6)
    assert c.b == pytest.approx(a.b, rel=1e-5)


# -- records that are not a clean sinusoid: one line naming the file and the problem -----------

def _write(tmp_path, name, t, u, x):
    path = tmp_path / name
    pd.DataFrame({"time [s]": t, "force [N]": u, "displacement [m]": x}).to_csv(path, index=False)
    return path


def _error(path, frequency=1.0, **kw) -> str:
    with pytest.raises(DataError) as info:
        analyse_compression_file(path, frequency=frequency, length=LENGTH, area=AREA, **kw)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_wrong_frequency_is_reported_with_the_dominant_one(tmp_path):
    rec = compression_record(3e4, 400.0, frequency=2.0, cycles=6)
    msg = _error(_write(tmp_path, "r.csv", rec["time"], rec["force"], rec["displacement"]), frequency=1.0)
    assert "not a clean 1 Hz sinusoid" in msg and "dominant frequency 2 Hz" in msg


def test_square_wave_is_not_a_clean_sinusoid(tmp_path):
    rec = compression_record(3e4, 400.0, cycles=4)
    clipped = np.clip(rec["force"], -0.2 * rec["force"].max(), 0.2 * rec["force"].max())
    msg = _error(_write(tmp_path, "clip.csv", rec["time"], np.sign(clipped), rec["displacement"]),
                 min_explained=0.95)
    assert "force variance" in msg


def test_too_few_cycles_too_few_samples_time_order(tmp_path):
    rec = compression_record(3e4, 400.0, cycles=1.5)
    assert "1.50 cycles" in _error(_write(tmp_path, "short.csv", rec["time"], rec["force"], rec["displacement"]))
    rec = compression_record(3e4, 400.0, frequency=1.0, sample_rate=3.0, cycles=30)
    assert "samples per cycle" in _error(_write(tmp_path, "slow.csv", rec["time"], rec["force"],
                                                rec["displacement"]))
    rec = compression_record(3e4, 400.0, cycles=3)
    t = rec["time"].copy()
    t[10] = t[9]
    assert "time does not increase at data row 11" in _error(_write(tmp_path, "t.csv", t, rec["force"],
                                                                    rec["displacement"]))


def test_swapped_or_reversed_channels(tmp_path):
    rec = compression_record(3e4, 400.0, cycles=3)
    assert "negative stiffness" in _error(_write(tmp_path, "neg.csv", rec["time"], -rec["force"],
                                                 rec["displacement"]))
    # the force lagging the displacement: negative damping
    rec = compression_record(3e4, -400.0, cycles=3)
    assert "negative damping" in _error(_write(tmp_path, "lag.csv", rec["time"], rec["force"], rec["displacement"]))


def test_constant_channel_and_bad_columns(tmp_path):
    rec = compression_record(3e4, 400.0, cycles=3)
    assert "does not oscillate" in _error(_write(tmp_path, "flat.csv", rec["time"], rec["force"],
                                                 np.full_like(rec["time"], 1e-3)))
    path = tmp_path / "cols.csv"
    pd.DataFrame({"time": rec["time"], "force": rec["force"]}).to_csv(path, index=False)
    assert "no displacement column" in _error(path)
    path = tmp_path / "text.csv"
    frame = pd.DataFrame({"time": rec["time"], "force": rec["force"].astype(object), "x": rec["displacement"]})
    frame.loc[5, "force"] = "overload"
    frame.to_csv(path, index=False)
    assert "column 'force', data row 6: not a number ('overload')" in _error(path)
    path = tmp_path / "unit.csv"
    pd.DataFrame({"time [s]": rec["time"], "force [lbf]": rec["force"], "x": rec["displacement"]}).to_csv(path)
    assert "unknown force unit 'lbf'" in _error(path)
    assert "file not found" in _error(tmp_path / "missing.csv")
