"""``file`` backend formats: t,u,y records (unchanged behaviour) and lab run directories."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.errors import DataError
from mbus_framework.interfaces.excitation import Waveform
from mbus_framework.pipeline.storage import write_waveforms
from mbus_plugins.backends.file import FileBackend, FileOptions, sniff_format
from mbus_plugins.instruments.shots import (
    ProcessingOptions,
    Reference,
    Shot,
    combine,
    save_excitation,
    save_shot,
    write_acquisition,
)

RATE = 1.0e6


def designed(n_bits=63, per_bit=4, seed=1):
    bits = np.random.default_rng(seed).integers(0, 2, n_bits) * 2 - 1
    u = np.repeat(bits, per_bit).astype(float)
    return Waveform(np.arange(u.size) / RATE, u)


def context(wave=None) -> AcquisitionContext:
    return AcquisitionContext(wave or designed(), None, None, None, None, "<config>")


def fake_shot(wave, start, n=400, dt=1.0 / RATE, scale=0.5, vdiv=(0.2, 0.5), seed=0):
    """A two-channel shot: the burst at sample ``start``; y a delayed copy (codes, volts)."""
    rng = np.random.default_rng(seed)
    ref = Reference(wave.u, wave.sample_rate).on_grid(dt)
    u = np.zeros(n)
    u[start:start + ref.size] = scale * ref[: n - start]
    y = np.roll(u, 7) * 0.3 + 0.002 * rng.standard_normal(n)
    u_raw = np.round(u / vdiv[0] * 25).astype(np.int16)
    y_raw = np.round(y / vdiv[1] * 25).astype(np.int16)
    meta = {"index": 1, "u_volts_per_div": vdiv[0], "y_volts_per_div": vdiv[1], "counts_per_division": 25.0}
    return Shot(dt, u_raw * vdiv[0] / 25, y_raw * vdiv[1] / 25, u_raw, y_raw, meta)


def make_run(tmp_path, shots, wave, status="complete", processing=None):
    shot_dir = tmp_path / "shots"
    points = np.round(wave.u * 2047).astype(np.int16)
    save_excitation(shot_dir, wave.t, wave.u, points, RATE, 1)
    for i, s in enumerate(shots, start=1):
        save_shot(shot_dir, i, s)
    write_acquisition(shot_dir, {"status": status, "shots_requested": 3, "shots_saved": len(shots),
                                 "processing": (processing or ProcessingOptions()).model_dump(mode="json"),
                                 "error": None if status == "complete" else "GDS-2062: read CH1: short read"})
    return shot_dir


# -- t,u,y records: existing behaviour ----------------------------------------------------------
def test_tuy_csv_and_npz_still_work(tmp_path):
    t = np.arange(50) * 1e-6
    write_waveforms(tmp_path / "rec.csv", t, np.sin(t * 1e5), np.cos(t * 1e5))
    np.savez(tmp_path / "rec.npz", t=t, u=np.sin(t * 1e5), y=np.cos(t * 1e5))
    for name in ("rec.csv", "rec.npz"):
        m = FileBackend(FileOptions(path=str(tmp_path / name))).acquire(context())
        assert m.u == pytest.approx(np.sin(t * 1e5)) and m.dt == pytest.approx(1e-6)
    assert sniff_format(tmp_path / "rec.csv") == "tuy"
    assert sniff_format(tmp_path) == "lab_run"


def test_tuy_errors_are_unchanged(tmp_path):
    (tmp_path / "bad.csv").write_text("t,u\n0,1\n")
    with pytest.raises(DataError, match=r"bad.csv: missing column\(s\) y in header 't,u'"):
        FileBackend(FileOptions(path=str(tmp_path / "bad.csv"))).acquire(context())
    with pytest.raises(DataError, match=r"nope.csv: file not found"):
        FileBackend(FileOptions(path=str(tmp_path / "nope.csv"))).acquire(context())
    (tmp_path / "x.dat").write_text("1")
    with pytest.raises(DataError, match=r"x.dat: unsupported file type '.dat'"):
        FileBackend(FileOptions(path=str(tmp_path / "x.dat"))).acquire(context())


# -- lab run directories ---------------------------------------------------------------------
def test_run_directory_is_aligned_and_averaged(tmp_path):
    wave = designed()
    shots = [fake_shot(wave, 40, seed=1), fake_shot(wave, 43, seed=2)]
    make_run(tmp_path, shots, wave)
    m = FileBackend(FileOptions(path=str(tmp_path))).acquire(context())
    assert m.meta["lags_samples"] == [40, 43] and m.meta["shots_averaged"] == 2
    assert m.u.size == wave.u.size
    assert m.u == pytest.approx(0.5 * wave.u, abs=0.01)
    # Same result when pointed at the shots/ folder itself.
    m2 = FileBackend(FileOptions(path=str(tmp_path / "shots"))).acquire(context())
    assert np.array_equal(m.u, m2.u) and np.array_equal(m.y, m2.y)


def test_run_directory_options_override_saved_processing(tmp_path):
    wave = designed()
    make_run(tmp_path, [fake_shot(wave, 40)], wave,
             processing=ProcessingOptions(u_gain=2.0, y_gain=10.0))
    saved = FileBackend(FileOptions(path=str(tmp_path))).acquire(context())
    assert saved.meta["u_gain"] == 2.0 and np.max(saved.u) == pytest.approx(1.0, abs=0.01)
    raw = FileBackend(FileOptions(path=str(tmp_path), processing={"align": {"enabled": False}})).acquire(context())
    assert raw.u.size == 400 and raw.meta["aligned"] is False
    rescaled = FileBackend(FileOptions(path=str(tmp_path), counts_per_division=50.0)).acquire(context())
    assert rescaled.u == pytest.approx(saved.u / 2) and rescaled.y == pytest.approx(saved.y / 2)


def test_designed_input_option(tmp_path):
    wave = designed()
    make_run(tmp_path, [fake_shot(wave, 40)], wave)
    m = FileBackend(FileOptions(path=str(tmp_path), processing={"input": "designed"})).acquire(context())
    assert m.u == pytest.approx(m.meta["designed_peak_v"] * wave.u)
    assert m.meta["designed_peak_v"] == pytest.approx(0.5, rel=0.01)


def test_partial_run_warns(tmp_path):
    wave = designed()
    make_run(tmp_path, [fake_shot(wave, 40)], wave, status="failed")
    m = FileBackend(FileOptions(path=str(tmp_path))).acquire(context())
    assert m.meta["warnings"] == ["acquisition failed: 1 of 3 shots saved (GDS-2062: read CH1: short read)"]


def test_run_directory_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match=r"no saved shots"):
        FileBackend(FileOptions(path=str(tmp_path))).acquire(context())
    wave = designed()
    shot_dir = make_run(tmp_path, [fake_shot(wave, 40)], wave)
    (shot_dir / "shot_0002.npz").write_bytes(b"not a zip")
    with pytest.raises(DataError, match=r"shot_0002.npz: unreadable shot file"):
        FileBackend(FileOptions(path=str(tmp_path))).acquire(context())
    save_shot(shot_dir, 2, fake_shot(wave, 40, dt=2e-6))
    with pytest.raises(DataError, match=r"shot 2 has dt 2e-06 s / 400 samples, shot 1 has 1e-06 s / 400"):
        FileBackend(FileOptions(path=str(tmp_path))).acquire(context())
    (shot_dir / "shot_0002.npz").unlink()
    acq = json.loads((shot_dir / "acquisition.json").read_text())
    (shot_dir / "acquisition.json").write_text(json.dumps(dict(acq, format="other/9")))
    with pytest.raises(DataError, match=r"acquisition.json: unknown format 'other/9'"):
        FileBackend(FileOptions(path=str(tmp_path))).acquire(context())


# -- shot processing details -----------------------------------------------------------------
def test_alignment_across_different_sample_grids():
    """Scope dt (0.4 us) differs from the generator's point rate (1 MHz)."""
    wave = designed(per_bit=5)
    shot = fake_shot(wave, 30, n=900, dt=0.4e-6)
    t, u, y, meta = combine([shot], Reference(wave.u, RATE), ProcessingOptions(), "mem")
    assert meta["lags_samples"] == [30]
    assert u.size == int(wave.u.size * 1e-6 / 0.4e-6 + 1e-6)
    assert t[1] == pytest.approx(0.4e-6)


def test_alignment_failures():
    wave = designed()
    inverted = fake_shot(wave, 40)
    inverted.u = -inverted.u
    with pytest.raises(DataError, match=r"shot 1: .*does not match.*\(the channel looks inverted\)"):
        combine([inverted], Reference(wave.u, RATE), ProcessingOptions(), "mem")
    late = fake_shot(wave, 0)
    late.u = np.concatenate([late.u[20:], np.zeros(20)])  # the record began after the burst
    with pytest.raises(DataError, match=r"the record starts 20 samples after the excitation began"):
        combine([late], Reference(wave.u, RATE), ProcessingOptions(), "mem")
