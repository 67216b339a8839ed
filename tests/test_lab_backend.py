"""``lab`` backend against fake instruments on pseudo-terminals, with a simulated medium.

Fast tests drive :class:`LabBackend` directly; the end-to-end test runs ``mbus-run`` with a
config that points the ``lab`` backend at the fakes and checks the recovered parameters, then
re-fits from the saved run directory with the ``file`` backend (no instruments).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.errors import DataError, InstrumentError
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.backends.file import FileBackend, FileOptions
from mbus_plugins.backends.lab import LabBackend, LabOptions
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.instruments.shots import load_run
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

pytestmark = [
    pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs POSIX pseudo-terminals"),
]
pytest.importorskip("pyvisa_py", reason="pyvisa-py opens the scope's ASRL resource")

from fakes.bench import Bench  # noqa: E402
from fakes.ds340 import FakeDS340  # noqa: E402
from fakes.gds2000 import FakeGDS2000  # noqa: E402

TRUTH = {"k_sigma": 3.0e8, "b_sigma": 15.0, "k_tau": 5.0e7, "b_tau": 12.0}
SAMPLE = {"length": 0.05, "diameter": 0.0254, "density": 1000.0}
# 5 MS/s, 12 samples per bit: uploaded as one point per bit (127 points) at 40 MHz / 96 exactly.
PRBS = {"order": 7, "bit_width": 2.4e-6, "amplitude": 1.0, "sample_rate": 5.0e6}
RECORD_POINTS = 2500  # 50 us/div -> dt = 200 ns, the excitation's own grid


def model() -> KelvinVoigtChain:
    return KelvinVoigtChain(Sample(**SAMPLE), KelvinVoigtOptions(n_elements=10))


@pytest.fixture
def rig():
    with FakeDS340() as gen, FakeGDS2000(record_points=RECORD_POINTS) as scope:
        bench = Bench(gen, scope, model(), list(TRUTH.values()), noise=0.01, seed=3)
        yield gen, scope, bench
        assert gen.errors == [] and scope.errors == []


def lab_options(generator_device, scope_device, shots=3, **extra) -> dict:
    """Lab options pointing at the fakes; ``extra`` sections are merged in."""
    gen, scope = generator_device, scope_device
    options = {
        "generator": {"port": gen.port, "timeout": 0.3, "ready_timeout": 0.3, "amplitude_vpp": 2.0,
                      "upload_decimation": 12},
        "scope": {"resource": f"ASRL{scope.port}::INSTR", "timeout": 0.3, "ch1": {"scale": 0.5},
                  "ch2": {"scale": 1.0}, "timebase": 50e-6, "settle": 0.0, "arm_delay": 0.0},
        "shots": shots,
    }
    for key, value in extra.items():
        options[key] = {**options.get(key, {}), **value} if isinstance(value, dict) else value
    return options


def context(run_dir: Path) -> AcquisitionContext:
    wave = Prbs(PrbsOptions(**PRBS)).waveform()
    return AcquisitionContext(wave, Sample(**SAMPLE), model(), None, run_dir, "<config>")


def acquire(options: dict, run_dir: Path):
    return LabBackend(LabOptions(**options)).acquire(context(run_dir))


def test_acquire_saves_every_shot_and_returns_the_aligned_average(rig, tmp_path):
    gen, scope, bench = rig
    m = acquire(lab_options(gen, scope, shots=3), tmp_path)
    shot_dir = tmp_path / "shots"
    assert sorted(p.name for p in shot_dir.glob("shot_*.npz")) == ["shot_0001.npz", "shot_0002.npz", "shot_0003.npz"]
    acq = json.loads((shot_dir / "acquisition.json").read_text())
    assert acq["status"] == "complete" and acq["shots_saved"] == 3 and acq["error"] is None
    assert acq["instruments"]["generator"]["identity"].startswith("StanfordResearchSystems,DS340")
    assert acq["instruments"]["scope"]["identity"].startswith("GW,GDS-2062")
    assert acq["instruments"]["generator"]["settings"]["sample_rate_hz"] == pytest.approx(40e6 / 96)
    # The generator got the designed PRBS as one point per bit at +-2047.
    wave = Prbs(PrbsOptions(**PRBS)).waveform()
    assert np.array_equal(gen.points, np.round(wave.u[::12] * 2047).astype(np.int16))
    assert gen.triggers == 3 and scope.captures == 3
    # Alignment found each shot's burst start (pre-trigger plus jitter).
    assert m.meta["lags_samples"] == bench.starts
    assert m.dt == pytest.approx(2e-7) and m.u.size == wave.u.size
    # Recorded excitation (volts) matches the designed one scaled to 1 V within quantisation + noise.
    assert np.max(np.abs(m.u - wave.u)) < 0.1
    assert m.meta["shots_averaged"] == 3


def test_refit_from_the_run_directory_gives_the_same_record(rig, tmp_path):
    gen, scope, _ = rig
    m = acquire(lab_options(gen, scope, shots=2), tmp_path)
    again = FileBackend(FileOptions(path=str(tmp_path))).acquire(context(None))
    assert np.array_equal(again.t, m.t) and np.array_equal(again.u, m.u) and np.array_equal(again.y, m.y)
    assert again.meta["acquisition_status"] == "complete" and again.meta["warnings"] == []


@pytest.mark.parametrize("fault, step", [
    ("scope_disconnect", r"GDS-2062: read CH1: (connection to ASRL\S+ failed \(disconnected\?\)|short read)"),
    ("scope_timeout", r"GDS-2062: read CH1: short read: the 5008-byte block incomplete after the 0.3 s timeout"),
    ("scope_garbage", r"GDS-2062: read CH1: garbage reply b'\\xff\\xfe' to ':ACQ1:MEM\?'"),
    ("generator_disconnect", r"DS340: trigger: serial port /dev/\S+ failed \(disconnected\?\)"),
])
def test_failures_mid_run_keep_the_saved_shots(rig, tmp_path, fault, step):
    gen, scope, _ = rig
    if fault == "generator_disconnect":
        gen.disconnect_on_trigger = 3
    else:
        scope.fault_from_read = 5  # shots 1 and 2 read two channels each; shot 3 fails on CH1
        if fault == "scope_disconnect":
            scope.disconnect_in_block = 700
        elif fault == "scope_timeout":
            scope.truncate_block = 1200
        else:
            scope.block_override = b"\xff\xfe\x00garbage\n"
    with pytest.raises(InstrumentError, match="^" + step):
        acquire(lab_options(gen, scope, shots=4), tmp_path)
    run = load_run(tmp_path)
    assert [f.name for f in run.files] == ["shot_0001.npz", "shot_0002.npz"]
    assert run.acquisition["status"] == "failed" and run.acquisition["shots_saved"] == 2
    assert run.acquisition["error"].startswith(step.split(":")[0])
    # The partial run re-fits without instruments and says what happened.
    m = FileBackend(FileOptions(path=str(tmp_path))).acquire(context(None))
    assert m.meta["shots_averaged"] == 2
    assert m.meta["warnings"][0].startswith("acquisition failed: 2 of 4 shots saved")


def test_rejected_generator_command_stops_before_any_shot(rig, tmp_path):
    gen, scope, _ = rig
    gen.reject["MENA"] = 32
    with pytest.raises(InstrumentError, match=r"^DS340: configure: 'MENA 1' rejected: \*ESR\? = 32"):
        acquire(lab_options(gen, scope), tmp_path)
    acq = json.loads((tmp_path / "shots" / "acquisition.json").read_text())
    assert acq["status"] == "failed" and acq["shots_saved"] == 0 and "MENA 1" in acq["error"]
    assert gen.triggers == 0


def test_swapped_channels_are_caught_by_the_alignment_check(rig, tmp_path):
    gen, scope, _ = rig
    options = lab_options(gen, scope, shots=1, scope={"excitation_channel": 2, "response_channel": 1})
    with pytest.raises(DataError, match=r"shot 1: the excitation channel does not match the designed excitation"):
        acquire(options, tmp_path)
    assert (tmp_path / "shots" / "shot_0001.npz").is_file()  # the measurement itself is kept


def test_options_are_strict():
    with pytest.raises(Exception, match="extra"):
        LabOptions(generator={"port": "x", "baud": 9600}, scope={})


def test_mbus_run_end_to_end_recovers_the_medium(rig, tmp_path):
    """mbus-run with the lab backend against fakes whose sample is a simulated Kelvin-Voigt chain."""
    from mbus_framework.cli import main

    gen, scope, _ = rig
    config = {
        "title": "lab rig against fake instruments",
        "sample": SAMPLE,
        "model": {"name": "kelvin_voigt", "options": {"n_elements": 10},
                  "initial": {k: 1.3 * v for k, v in TRUTH.items()}},
        "excitation": {"name": "prbs", "options": PRBS},
        "backend": {"name": "lab", "options": lab_options(gen, scope, shots=4)},
        "compensator": {"name": "none"},
        "solver": {"name": "scipy_lm", "options": {}},
        "output": {"plots": False},
    }
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(config))
    out = tmp_path / "run"
    assert main([str(path), "-o", str(out), "--no-plots", "-q"]) == 0
    result = json.loads((out / "result.json").read_text())
    for name, true in TRUTH.items():
        assert result["parameters"][name] == pytest.approx(true, rel=0.02), name
    assert len(list((out / "shots").glob("shot_*.npz"))) == 4

    # Re-fit from the run directory without instruments.
    config["backend"] = {"name": "file", "options": {"path": str(out)}}
    path.write_text(yaml.safe_dump(config))
    again = tmp_path / "refit"
    assert main([str(path), "-o", str(again), "--no-plots", "-q"]) == 0
    refit = json.loads((again / "result.json").read_text())
    for name in TRUTH:
        assert refit["parameters"][name] == pytest.approx(result["parameters"][name], rel=1e-6), name
