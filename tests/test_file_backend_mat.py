"""``file`` backend: MATLAB .mat records (shipped thetascan files and synthetic files)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.io import loadmat, savemat

from mbus_framework.errors import DataError
from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.pipeline.config import validate_options
from mbus_plugins.backends.file import FileBackend, FileOptions, sniff_format

THETASCAN = Path(__file__).resolve().parents[1] / "examples" / "real" / "thetascan"
MAPPING = {"input": "s_ref", "output": "s", "time": "t", "thickness": "h", "density": "rho", "temperature": "Temp"}


def acquire(path, **options):
    o = validate_options(FileOptions, {"path": str(path), **options}, "backend.options")
    return FileBackend(o).acquire(AcquisitionContext(None, None, None, None, None, "<config>"))


def write(path: Path, n=300, m=4, dt=1e-8, **extra) -> Path:
    t = 1e-4 + np.arange(n) * dt
    u = np.sin(2 * np.pi * 1e6 * t)[:, None]
    s = np.stack([np.cos(2 * np.pi * (1 + k) * 1e6 * t) for k in range(m)], axis=1)
    savemat(path, {"t": t[:, None], "s_ref": u, "s": s, "h": 0.004, "rho": np.uint16(1185), "Temp": 21.5, **extra})
    return path


@pytest.mark.parametrize("name, n, h, rho, temp", [("VW100a.mat", 1601, 3.994e-3, 1185, 22.6),
                                                  ("VW0.mat", 1364, 2.64e-3, 1115, 18.6)])
def test_shipped_thetascan_files_load_with_the_same_mapping(name, n, h, rho, temp):
    path = THETASCAN / name
    m = acquire(path, variables=MAPPING, pretrigger=False)
    raw = loadmat(path)
    np.testing.assert_array_equal(m.u, raw["s_ref"][:, 0])
    np.testing.assert_array_equal(m.y, raw["s"][:, 0])  # column 0: normal incidence
    assert m.u.size == n
    assert m.dt == pytest.approx(1e-8, rel=1e-6)  # 100 MS/s
    assert m.t[0] == 0.0 and m.meta["time_start_s"] == pytest.approx(raw["t"][0, 0])
    assert m.meta["sample_from_file"] == pytest.approx({"length": h, "density": rho})
    assert m.meta["fluid_from_file"]["temperature_C"] == pytest.approx(temp)
    assert m.meta["variables"] == MAPPING and m.meta["column"] == 0
    assert (THETASCAN / "LICENSE").is_file() and "GPL-3.0" in (THETASCAN / "CITATION.cff").read_text()


@pytest.mark.parametrize("name", ["VW100a.mat", "VW0.mat"])
def test_shipped_records_are_cut_where_the_earlier_channel_starts(name):
    """Substitution records: the shot through the plate leads the reference; neither is cut short."""
    raw = loadmat(THETASCAN / name)
    u, y = raw["s_ref"][:, 0], raw["s"][:, 0]
    m = acquire(THETASCAN / name, variables=MAPPING)
    p = m.meta["pretrigger"]
    k = p["samples"]
    assert p["onset_y_samples"] < p["onset_u_samples"] and k == p["onset_y_samples"] > 100
    # the pulses stand far above the pre-trigger: the cut keeps all of both
    assert np.abs(y[:k]).max() < 0.05 * np.abs(y).max() and np.abs(u[:k]).max() < 0.05 * np.abs(u).max()
    np.testing.assert_allclose(m.u, u[k:] - u[:k].mean())
    np.testing.assert_allclose(m.y, y[k:] - y[:k].mean())
    assert m.meta["time_start_s"] == pytest.approx(raw["t"][k, 0])


def test_only_the_path_changed_loads_another_file_of_the_same_layout(tmp_path):
    a = acquire(write(tmp_path / "a.mat", n=300), variables=MAPPING)
    b = acquire(write(tmp_path / "b.mat", n=500, dt=2e-8, h=0.002), variables=MAPPING)
    assert (a.u.size, b.u.size) == (300, 500)
    assert b.dt == pytest.approx(2e-8) and b.meta["sample_from_file"]["length"] == 0.002


def test_column_selects_a_column_of_the_2d_output(tmp_path):
    path = write(tmp_path / "r.mat")
    m = acquire(path, variables={**MAPPING, "column": 2})
    np.testing.assert_allclose(m.y, loadmat(path)["s"][:, 2])
    assert m.meta["column"] == 2


def test_sample_rate_or_interval_replaces_a_time_variable_and_defaults_are_t_u_y(tmp_path):
    u, y = np.arange(40.0), np.arange(40.0) ** 2
    savemat(tmp_path / "tuy.mat", {"t": np.arange(40) * 1e-6, "u": u, "y": y})
    m = acquire(tmp_path / "tuy.mat")  # default mapping: t, u, y
    assert sniff_format(tmp_path / "tuy.mat") == "mat"
    np.testing.assert_array_equal(m.y, y)
    assert m.dt == pytest.approx(1e-6)
    savemat(tmp_path / "uy.mat", {"x": u, "z": y})
    m = acquire(tmp_path / "uy.mat", variables={"input": "x", "output": "z", "sample_rate": 2e6})
    assert m.dt == pytest.approx(5e-7) and "time" not in m.meta["variables"]
    m = acquire(tmp_path / "uy.mat", variables={"input": "x", "output": "z", "sample_interval": 1e-7})
    assert m.dt == pytest.approx(1e-7)


@pytest.mark.parametrize("variables, extra, words", [
    ({**MAPPING, "output": "sig"}, {}, ["no variable 'sig'", "variables.output", "s_ref"]),
    ({**MAPPING, "time": "time"}, {}, ["no variable 'time'", "variables.time", "sample_interval"]),
    ({**MAPPING, "column": 4}, {}, ["variables.column = 4", "4 columns"]),
    ({**MAPPING, "thickness": "missing"}, {}, ["'missing'", "variables.thickness"]),
    ({**MAPPING, "density": "t"}, {}, ["'t'", "variables.density", "300 values"]),
    ({**MAPPING, "output": "bad"}, {"bad": np.zeros((300, 2, 2))}, ["'bad'", "3 dimensions"]),
    ({**MAPPING, "output": "txt"}, {"txt": "hello"}, ["'txt'", "variables.output", "not real numbers"]),
    ({**MAPPING, "output": "short"}, {"short": np.zeros(100)}, ["'short' has 100", "300"]),
    ({**MAPPING, "thickness": "neg"}, {"neg": -1.0}, ["'neg'", "positive"]),
])
def test_malformed_files_give_one_line_naming_file_and_variable(tmp_path, variables, extra, words):
    path = write(tmp_path / "bad.mat", **extra)
    with pytest.raises(DataError) as err:
        acquire(path, variables=variables)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg
    for w in words:
        assert w in msg, (w, msg)


def test_not_a_mat_file_and_v73_without_h5py(tmp_path):
    junk = tmp_path / "junk.mat"
    junk.write_text("t,u,y\n1,2,3\n")
    with pytest.raises(DataError, match=r"junk\.mat: not a readable MATLAB \.mat file"):
        acquire(junk)
    v73 = tmp_path / "v73.mat"
    v73.write_bytes(b"MATLAB 7.3 MAT-file".ljust(512, b" ") + b"\x89HDF\r\n\x1a\n" + bytes(64))
    try:
        import h5py  # noqa: F401
    except ImportError:
        with pytest.raises(DataError, match=r"v73\.mat: MATLAB v7\.3 \(HDF5\) file; reading it needs h5py"):
            acquire(v73)
    else:
        with pytest.raises(DataError, match=r"v73\.mat: not a readable MATLAB v7\.3 file"):
            acquire(v73)


def test_variables_on_a_non_mat_file_is_refused(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("t,u,y\n" + "\n".join(f"{k * 1e-6},{k},{k}" for k in range(20)) + "\n")
    with pytest.raises(DataError, match="variables applies to MATLAB .mat files only"):
        acquire(p, variables={"input": "u"})


def test_interval_and_rate_together_is_a_config_error(tmp_path):
    with pytest.raises(Exception, match="sample_interval or sample_rate"):
        acquire(write(tmp_path / "r.mat"), variables={"sample_interval": 1e-8, "sample_rate": 1e8})
