"""Rheometer sweeps at a chosen frequency, and the conventional sheet (replicates, joins, errors)."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mbus_framework.analysis.conventional.rheometer import analyse_sweep, analyse_sweep_file, interpolate_at
from mbus_framework.analysis.conventional.sheet import conventional_table, read_sheet
from mbus_framework.analysis.conventional.synthetic import (compression_record, rheometer_sweep,
                                                            write_compression_csv, write_sweep_csv)
from mbus_framework.errors import DataError


@settings(max_examples=30)
@given(storage=st.floats(1e3, 1e8), viscosity=st.floats(1.0, 1e5), f0=st.floats(0.05, 15.0),
       n_e=st.floats(-0.3, 0.3), n_eta=st.floats(-1.0, 0.3))
def test_power_law_sweep_is_recovered_exactly_between_grid_points(storage, viscosity, f0, n_e, n_eta):
    sweep = rheometer_sweep(storage, viscosity, f0=f0, storage_exponent=n_e, viscosity_exponent=n_eta)
    value = analyse_sweep(sweep["frequency"], sweep["storage"], viscosity=sweep["viscosity"], f0=f0)
    assert value.storage_modulus == pytest.approx(storage, rel=1e-9)
    assert value.dynamic_viscosity == pytest.approx(viscosity, rel=1e-9)
    # without eta' the loss modulus gives it: eta' = E'' / w
    from_loss = analyse_sweep(sweep["frequency"], sweep["storage"], loss=sweep["loss"], f0=f0)
    assert from_loss.dynamic_viscosity == pytest.approx(viscosity, rel=1e-9)


def test_interpolation_is_linear_in_log_frequency_and_log_value():
    rng = np.random.default_rng(0)
    f = np.sort(rng.uniform(0.1, 20, 12))
    v = rng.uniform(1, 100, 12)
    for f0 in rng.uniform(f[0], f[-1], 20):
        ref = np.exp(np.interp(np.log(f0), np.log(f), np.log(v)))
        assert interpolate_at(f, v, f0) == pytest.approx(ref, rel=1e-12)
    signed = v - 50  # non-positive values: linear in log f
    for f0 in rng.uniform(f[0], f[-1], 5):
        assert interpolate_at(f, signed, f0) == pytest.approx(np.interp(np.log(f0), np.log(f), signed))


def test_sweep_file_units_and_errors(tmp_path):
    sweep = rheometer_sweep(1.66e5, 436.0)
    path = write_sweep_csv(tmp_path / "s.csv", sweep)  # omega [rad/s], G' [Pa], ...
    assert analyse_sweep_file(path).storage_modulus == pytest.approx(1.66e5, rel=1e-6)
    kpa = tmp_path / "kpa.csv"
    pd.DataFrame({"frequency (Hz)": sweep["frequency"], "E' (kPa)": sweep["storage"] / 1e3,
                  "E'' (kPa)": sweep["loss"] / 1e3}).to_csv(kpa, index=False)
    value = analyse_sweep_file(kpa, f0=10.0)
    assert value.storage_modulus == pytest.approx(1.66e5, rel=1e-6)
    assert value.dynamic_viscosity == pytest.approx(436.0, rel=1e-6)
    with pytest.raises(DataError, match=r"s\.csv: 20 Hz is outside the sweep \(0\.0159-15\.9 Hz\)"):
        analyse_sweep_file(path, f0=20.0)
    bad = tmp_path / "nostorage.csv"
    pd.DataFrame({"omega": sweep["frequency"], "eta'": sweep["viscosity"]}).to_csv(bad, index=False)
    with pytest.raises(DataError, match="no storage column"):
        analyse_sweep_file(bad)
    dup = tmp_path / "dup.csv"
    pd.DataFrame({"f": [1.0, 1.0, 20.0], "G'": [1, 2, 3], "eta'": [1, 2, 3]}).to_csv(dup, index=False)
    with pytest.raises(DataError, match="1 Hz appears twice"):
        analyse_sweep_file(dup)


def _sheet(tmp_path, rows):
    path = tmp_path / "conventional.csv"
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def test_sheet_averages_replicates_and_uses_the_fit_se_for_one_record(tmp_path):
    rng = np.random.default_rng(5)
    area, length = math.pi * 0.01 ** 2, 0.03
    rows, truth = [], {}
    for sid, (E, eta, G, etap) in {"A": (2e6, 4e4, 1e5, 300.0), "B": (4e6, 6e4, 3e5, 700.0)}.items():
        k, b = E * area / length, eta * area / length
        n_comp = 1 if sid == "A" else 3
        for rep in range(n_comp):
            rec = compression_record(k, b, cycles=4, force_noise=0.02, rng=rng)
            write_compression_csv(tmp_path / f"{sid}_c{rep}.csv", rec)
            rows.append({"sample_id": sid, "test": "compression", "file": f"{sid}_c{rep}.csv",
                         "length [mm]": 30, "diameter [mm]": 20, "frequency": 1.0})
        for rep, scale in enumerate((0.97, 1.0, 1.05)):
            write_sweep_csv(tmp_path / f"{sid}_s{rep}.csv", rheometer_sweep(G * scale, etap * scale))
            rows.append({"sample_id": sid, "test": "rheometer", "file": f"{sid}_s{rep}.csv"})
        truth[sid] = (E, eta, G, etap)
    samples, records, problems = conventional_table(_sheet(tmp_path, rows))
    assert problems == [] and len(records) == len(rows)
    by_id = samples.set_index("sample_id")
    for sid in ("A", "B"):
        rec = records[records.sample_id == sid]
        comp = rec[rec.test == "compression"]
        shear = rec[rec.test == "rheometer"]
        assert by_id.loc[sid, "conv_E_sigma"] == pytest.approx(comp.E.mean())
        assert by_id.loc[sid, "conv_E_sigma_n"] == len(comp)
        assert by_id.loc[sid, "conv_E_tau"] == pytest.approx(shear.storage_modulus.mean())
        assert by_id.loc[sid, "conv_E_tau"] == pytest.approx(truth[sid][2] * (0.97 + 1 + 1.05) / 3, rel=1e-6)
        assert by_id.loc[sid, "conv_eta_tau_se"] == pytest.approx(shear.dynamic_viscosity.std(ddof=1) / math.sqrt(3))
        assert by_id.loc[sid, "conv_E_sigma"] == pytest.approx(truth[sid][0], rel=1e-2)
    assert by_id.loc["A", "conv_E_sigma_se"] == pytest.approx(records[records.sample_id == "A"].E_se.dropna().iloc[0])
    assert by_id.loc["B", "conv_E_sigma_se"] == pytest.approx(
        records[(records.sample_id == "B") & (records.test == "compression")].E.std(ddof=1) / math.sqrt(3))


def test_sheet_errors_name_the_row_and_the_files(tmp_path):
    rec = compression_record(3e4, 400.0, cycles=3)
    write_compression_csv(tmp_path / "ok.csv", rec)
    write_compression_csv(tmp_path / "fast.csv", compression_record(3e4, 400.0, frequency=3.0, cycles=9))
    base = {"sample_id": "A", "test": "compression", "file": "ok.csv", "length": 0.03, "diameter": 0.02,
            "frequency": 1.0}
    with pytest.raises(DataError, match=r"row 2, column 'test': 'tension' \(choose one of: compression, rheometer\)"):
        read_sheet(_sheet(tmp_path, [{**base, "test": "tension"}]))
    with pytest.raises(DataError, match="row 2: a compression row needs a positive frequency"):
        read_sheet(_sheet(tmp_path, [{**base, "frequency": None}]))
    with pytest.raises(DataError, match="unknown column\\(s\\) 'operator'"):
        read_sheet(_sheet(tmp_path, [{**base, "operator": "JD"}]))
    path = _sheet(tmp_path, [base, {**base, "sample_id": "B", "file": "fast.csv"},
                             {**base, "sample_id": "C", "file": "gone.csv"}])
    with pytest.raises(DataError) as info:
        conventional_table(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith("2 of 3 conventional records unusable")
    assert "fast.csv: not a clean 1 Hz sinusoid" in message and "gone.csv: file not found" in message
    samples, records, problems = conventional_table(path, skip_bad=True)
    assert list(samples.sample_id) == ["A"] and len(problems) == 2
