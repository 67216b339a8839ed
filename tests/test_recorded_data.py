"""Recorded data first: a config with only sample, model, a file backend and solver fits a t,u,y
file and a GDS-2062 CSV pair; a given excitation is checked against the record; commands that
need a design say so in one line.

The records come from an independent simulator (scipy.signal on the chain rebuilt from the
dissertation's equations, :mod:`fakes.recording`), and from the shipped example.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from fakes.recording import POTATO, TABLE_3_1, prbs_burst, simulate, write_gds_raw, write_tuy
from mbus_framework.cli import main
from mbus_framework.errors import DataError
from mbus_framework.interfaces.excitation import Waveform
from mbus_framework.interfaces.backend import Measurement
from mbus_framework.pipeline.recorded_input import consistency_warnings, input_statistics
from mbus_plugins.instruments.shots import burst_start

REPO = Path(__file__).resolve().parents[1]


def minimal_config(path: Path, mat, backend_options: dict) -> Path:
    """Only sample, model, a file backend and solver: what a user with a recording writes."""
    path.write_text(yaml.safe_dump({
        "sample": mat.sample,
        "model": {"name": "kelvin_voigt", "options": {"n_elements": mat.n_elements}},
        "backend": {"name": "file", "options": backend_options},
        "solver": {"name": "scipy_lm"},
    }, sort_keys=False))
    return path


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_recovers(result: dict, truth: dict[str, float], rel: float = 0.02, n_se: float = 4.0) -> None:
    """Every property within ``n_se`` of the run's own standard errors and ``rel`` of the truth."""
    se = result["uncertainty"]["property_standard_errors"]
    for name, value in truth.items():
        estimate = result["properties"][name]
        assert abs(estimate - value) <= n_se * se[name], (name, estimate, value, se[name])
        assert estimate == pytest.approx(value, rel=rel), name


@pytest.mark.parametrize("mat", [POTATO, TABLE_3_1], ids=lambda m: m.name)
def test_minimal_config_fits_an_independent_tuy_record(tmp_path, capsys, mat):
    u = prbs_burst(mat, mat.n_samples)
    t, y = simulate(mat, u, seed=5)
    cfg = minimal_config(tmp_path / "run.yaml", mat, {"path": str(write_tuy(tmp_path / "record.csv", t, u, y))})
    code, out, err = run_cli(capsys, cfg, "-o", tmp_path / "out", "--no-plots")
    assert code == 0, err
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert_recovers(r, mat.properties)
    assert r["excitation"]["name"] == "recorded" and r["excitation"]["designed"] is False
    stats = r["excitation"]["input"]
    assert stats["n_samples"] == mat.n_samples and stats["sample_rate_hz"] == pytest.approx(mat.sample_rate)
    assert stats["crest_factor"] == pytest.approx(float(np.max(np.abs(u)) / np.sqrt(np.mean(u**2))))
    assert not [w for w in r["warnings"] if w.startswith("excitation")]
    saved = yaml.safe_load((tmp_path / "out" / "config.yaml").read_text())
    assert saved["excitation"] is None
    assert (tmp_path / "out" / "report.html").is_file()


@pytest.mark.parametrize("pre", [0, 137])
def test_minimal_config_fits_a_gds_csv_pair(tmp_path, capsys, pre):
    """Scope files without any design: the burst start is found on CH1 and the record is kept to
    its end (a record starting at the burst, pre = 0, is kept whole)."""
    mat = POTATO
    u = prbs_burst(mat, 3000, start=pre)
    t, y = simulate(mat, u, seed=9)
    period = 1.0 / mat.sample_rate
    write_gds_raw(tmp_path / "A0003CH1.CSV", u, 0.5, period, "CH1")  # volts are newtons here
    write_gds_raw(tmp_path / "A0003CH2.CSV", y, 0.1, period, "CH2")
    cfg = minimal_config(tmp_path / "run.yaml", mat, {"path": "A0003CH1.CSV", "response_path": "A0003CH2.CSV"})
    code, out, err = run_cli(capsys, cfg, "-o", tmp_path / "out", "--no-plots")
    assert code == 0, err
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    meta = json.loads((tmp_path / "out" / "measurement.json").read_text())["meta"]
    assert meta["burst_starts_samples"] == [pre]
    assert meta["aligned"].startswith("burst onset")
    assert r["fit"]["n_samples"] == 3000 - pre
    started_inside = [w for w in r["warnings"] if "not at rest at the start of the record" in w]
    assert len(started_inside) == (pre == 0)
    assert_recovers(r, mat.properties, rel=0.03)


def test_shipped_recorded_configs_have_only_the_four_sections_and_recover_the_truth(tmp_path, capsys):
    truth = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}
    for name in ("recorded.yaml", "recorded_gds2062.yaml"):
        path = REPO / "configs" / name
        data = yaml.safe_load(path.read_text())
        assert set(data) - {"title"} == {"sample", "model", "backend", "solver"}, name
        code, out, err = run_cli(capsys, path, "-o", tmp_path / name, "--no-plots")
        assert code == 0, err
        assert_recovers(json.loads((tmp_path / name / "result.json").read_text()), truth)


def test_shipped_example_is_what_its_script_makes(tmp_path):
    """The data files are reproducible byte for byte by the documented script."""
    import runpy

    script = runpy.run_path(str(REPO / "examples" / "recorded" / "make_recorded_example.py"))
    script["main"](["--out", str(tmp_path)])
    for name in ("potato_tuy.csv", "A0001CH1.CSV", "A0001CH2.CSV"):
        assert (tmp_path / name).read_bytes() == (REPO / "examples" / "recorded" / name).read_bytes(), name


# ---------------------------------------------------------------------------------------
# The burst start without a design
# ---------------------------------------------------------------------------------------
@settings(max_examples=30, deadline=None)
@given(pre=st.integers(8, 400), level=st.floats(-0.5, 0.5), noise=st.sampled_from([0.0, 1e-3, 1e-2]),
       kind=st.sampled_from(["prbs", "sine"]), seed=st.integers(0, 2**16))
def test_burst_start_is_found_within_a_sample(pre, level, noise, kind, seed):
    rng = np.random.default_rng(seed)
    n = pre + 600
    k = np.arange(n - pre)
    if kind == "prbs":
        burst = np.where(rng.random(60).repeat(10) < 0.5, -1.0, 1.0)
    else:  # starts at zero phase: its first samples are small
        burst = np.sin(2 * np.pi * k / 37.0)
    u = np.full(n, level) + rng.normal(0.0, noise, n)
    u[pre:pre + burst.size] += burst[: n - pre]
    found = burst_start(u, "test")
    # A zero-phase sine's first sample is exactly the rest level: starting one later loses nothing.
    assert pre - 1 <= found <= pre + (1 if kind == "sine" else 0), (found, pre)


def test_flat_excitation_channel_is_one_line():
    with pytest.raises(DataError, match="^x: the excitation channel is flat"):
        burst_start(np.zeros(100), "x")


# ---------------------------------------------------------------------------------------
# A given excitation with recorded data: checked against the record
# ---------------------------------------------------------------------------------------
def wave(u: np.ndarray, fs: float) -> Waveform:
    return Waveform(np.arange(u.size) / fs, u)


def record(u: np.ndarray, fs: float, **meta) -> Measurement:
    return Measurement(np.arange(u.size) / fs, u, np.zeros(u.size), meta=meta)


def test_consistent_design_raises_no_warning():
    u = prbs_burst(POTATO, 3000)
    assert consistency_warnings(wave(u, 25e6), record(u, 25e6)) == []


def test_each_inconsistency_is_named():
    u = prbs_burst(POTATO, 3000)
    assert "designed at 6.25 MS/s but the record is sampled at 25 MS/s" in \
        " ".join(consistency_warnings(wave(u, 6.25e6), record(u, 25e6)))
    short = consistency_warnings(wave(u, 25e6), record(u[:2000], 25e6))
    assert any("shorter than the designed excitation" in w for w in short)
    slow = prbs_burst(replace(POTATO, bit_width=2.0e-6), 3000)  # 2 us bits instead of 0.4 us: another band
    band = consistency_warnings(wave(slow, 25e6), record(u, 25e6))
    assert any("is this the excitation that was played?" in w for w in band)
    # Scope at 2 MS/s, aligned by cross-correlation: no rate warning, but it under-samples the PRBS.
    coarse = consistency_warnings(wave(u, 25e6), record(u[::12][:250], 25e6 / 12, lags_samples=[0]))
    assert not any("designed at" in w for w in coarse)
    assert any("under-samples the excitation" in w for w in coarse)


def test_input_statistics_against_analytic_values():
    """A sine of f0 on whole periods: crest factor sqrt 2, half and 95 % of the power at f0."""
    fs, f0, n = 1e6, 50e3, 4000
    u = 2.0 * np.sin(2 * np.pi * f0 * np.arange(n) / fs)
    s = input_statistics(u, 1 / fs)
    assert s["crest_factor"] == pytest.approx(np.sqrt(2), rel=1e-9)
    assert s["rms"] == pytest.approx(np.sqrt(2), rel=1e-9)
    assert s["median_frequency_hz"] == pytest.approx(f0) and s["f95_hz"] == pytest.approx(f0)
    lo, hi = s["band_3db_hz"]
    assert lo <= f0 <= hi and hi - lo < 4 * fs / (n // 8)  # a few Welch bins around the line


def test_tuy_record_with_a_mismatched_design_warns_in_the_result(tmp_path, capsys):
    cfg = minimal_config(tmp_path / "run.yaml", POTATO, {"path": str(REPO / "examples/recorded/potato_tuy.csv")})
    code, out, err = run_cli(capsys, cfg, "-o", tmp_path / "out", "--no-plots",
                             "--set", "excitation={name: prbs, options: {order: 9, bit_width: 2.5e-6, sample_rate: 6.25e6}}")
    assert code == 0, err
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert r["excitation"]["designed"] is True and r["excitation"]["name"] == "prbs"
    assert r["excitation"]["input"]["sample_rate_hz"] == pytest.approx(25e6)
    assert sum(w.startswith("excitation:") for w in r["warnings"]) == 3
    assert "WARNING: excitation: designed at 6.25 MS/s" in out


def test_gds_pair_with_a_design_is_aligned_by_it(tmp_path, capsys):
    """With the design the burst is found by cross-correlation and cut to its length."""
    cfg = REPO / "configs" / "recorded_gds2062.yaml"
    code, out, err = run_cli(capsys, cfg, "-o", tmp_path / "out", "--no-plots", "--set",
                             "excitation={name: prbs, options: {order: 7, bit_width: 0.4e-6, sample_rate: 25.0e6}}")
    assert code == 0, err
    meta = json.loads((tmp_path / "out" / "measurement.json").read_text())["meta"]
    assert meta["lags_samples"] == [400] and meta["correlations"][0] > 0.99
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert r["fit"]["n_samples"] == 1270 and r["warnings"] == []


# ---------------------------------------------------------------------------------------
# What needs a design says so in one line
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, fragment", [
    ([], "excitation: required by backend 'simulated' (it plays the excitation)"),
    (["--design-excitation"], "excitation: --design-excitation needs an excitation section"),
])
def test_commands_that_need_a_design_say_so(tmp_path, capsys, argv, fragment):
    if argv:
        cfg = REPO / "configs" / "recorded.yaml"
    else:
        data = yaml.safe_load((REPO / "configs" / "potato.yaml").read_text())
        data.pop("excitation")
        cfg = tmp_path / "no_excitation.yaml"
        cfg.write_text(yaml.safe_dump(data))
    code, out, err = run_cli(capsys, cfg, "-o", tmp_path / "out", *argv)
    assert code == 2
    assert err.count("\n") == 1 and fragment in err and "Traceback" not in err


def test_designed_input_without_a_design_is_one_line(tmp_path, capsys):
    code, out, err = run_cli(capsys, REPO / "configs" / "recorded_gds2062.yaml", "-o", tmp_path / "out",
                             "--set", "backend.options.processing={input: designed}")
    assert code == 2 and err.count("\n") == 1
    assert "processing.input 'designed' needs the designed excitation (an excitation section in the config)" in err


# ---------------------------------------------------------------------------------------
# Lab run folders need no excitation either
# ---------------------------------------------------------------------------------------
def test_lab_run_folder_without_a_config_excitation(tmp_path):
    """The waveform the generator played is saved with the shots: it aligns them; without it the
    burst onset does."""
    from mbus_plugins.backends.file import FileBackend, FileOptions
    from test_file_backend_formats import designed, fake_shot, make_run

    from mbus_framework.interfaces.backend import AcquisitionContext

    wave = designed()
    make_run(tmp_path, [fake_shot(wave, 40, seed=1), fake_shot(wave, 43, seed=2)], wave)
    no_design = AcquisitionContext(None, None, None, None, None, "<config>")
    m = FileBackend(FileOptions(path=str(tmp_path))).acquire(no_design)
    assert m.meta["lags_samples"] == [40, 43] and m.u.size == wave.u.size
    (tmp_path / "shots" / "excitation.npz").unlink()
    m = FileBackend(FileOptions(path=str(tmp_path))).acquire(no_design)
    assert m.meta["burst_starts_samples"] == [40, 43] and m.u.size == 400 - 43
    assert m.u[: wave.u.size] == pytest.approx(0.5 * wave.u, abs=0.01)
