"""``file`` backend: t,u,y records from CSV and NPZ; every bad file gives one line naming it."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.pipeline.config import validate_options
from mbus_framework.errors import DataError
from mbus_framework.interfaces.excitation import Waveform
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

N = 200
DT = 1e-6
T = np.arange(N) * DT
U = np.where(np.sin(2 * np.pi * 7e3 * T) >= 0, 1.0, -1.0)
Y = 1e-3 * np.sin(2 * np.pi * 11e3 * T)


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_manager(new_plugin_manager())


def acquire(path: Path, registry: Registry, config_dir: Path | None = None):
    """Acquire through the registered plugin with its options validated (stage 2)."""
    spec = registry.get("backend", "file")
    backend = spec.implementation(validate_options(spec.implementation.Options, {"path": str(path)}, "backend.options"))
    sample = Sample(0.02, 0.0254, 1000.0)
    context = AcquisitionContext(
        Waveform(T, U),
        sample,
        KelvinVoigtChain(sample, KelvinVoigtOptions(n_elements=3)),
        registry,
        None,
        str(config_dir / "run.yaml") if config_dir else "<config>",
    )
    return backend.acquire(context)


def write_csv(path: Path, header: str, rows) -> Path:
    lines = [header] + [",".join(str(v) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def good_rows():
    return [(repr(float(a)), repr(float(b)), repr(float(c))) for a, b, c in zip(T, U, Y)]


# ---------------------------------------------------------------------------------------
# Good files
# ---------------------------------------------------------------------------------------
def test_reads_csv(tmp_path, registry):
    m = acquire(write_csv(tmp_path / "rec.csv", "t,u,y", good_rows()), registry)
    np.testing.assert_allclose(m.t, T, rtol=0, atol=1e-18)
    np.testing.assert_array_equal(m.u, U)
    np.testing.assert_array_equal(m.y, Y)
    assert m.dt == pytest.approx(DT)
    assert m.truth is None


def test_reads_csv_with_columns_in_any_order_extra_columns_spaces_and_bom(tmp_path, registry):
    rows = [(c, "0", a, b) for a, b, c in good_rows()]
    path = tmp_path / "rec.csv"
    path.write_text("\ufeff Y , temp_C , T , U\n" + "\n".join(",".join(r) for r in rows) + "\n", encoding="utf-8")
    m = acquire(path, registry)
    np.testing.assert_array_equal(m.u, U)
    np.testing.assert_array_equal(m.y, Y)


def test_time_is_shifted_to_start_at_zero(tmp_path, registry):
    rows = [(repr(float(a) + 5e-3), b, c) for a, b, c in good_rows()]
    m = acquire(write_csv(tmp_path / "late.csv", "t,u,y", rows), registry)
    assert m.t[0] == 0.0
    assert m.dt == pytest.approx(DT, rel=1e-9)


def test_reads_npz(tmp_path, registry):
    np.savez(tmp_path / "rec.npz", t=T, u=U, y=Y)
    m = acquire(tmp_path / "rec.npz", registry)
    np.testing.assert_array_equal(m.u, U)
    np.testing.assert_array_equal(m.y, Y)


def test_relative_path_is_found_next_to_the_config(tmp_path, registry, monkeypatch):
    data_dir = tmp_path / "cfg"
    data_dir.mkdir()
    write_csv(data_dir / "rec.csv", "t,u,y", good_rows())
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    m = acquire(Path("rec.csv"), registry, config_dir=data_dir)
    np.testing.assert_array_equal(m.y, Y)


# ---------------------------------------------------------------------------------------
# Bad files: one line, naming the file and the problem
# ---------------------------------------------------------------------------------------
def _bad(tmp_path: Path, kind: str) -> Path:
    rows = good_rows()
    if kind == "missing column":
        return write_csv(tmp_path / "bad.csv", "t,u", [r[:2] for r in rows])
    if kind == "nan":
        rows[40] = (rows[40][0], "nan", rows[40][2])
        return write_csv(tmp_path / "bad.csv", "t,u,y", rows)
    if kind == "empty field":
        rows[40] = (rows[40][0], rows[40][1], "")
        return write_csv(tmp_path / "bad.csv", "t,u,y", rows)
    if kind == "inf":
        rows[3] = ("inf", rows[3][1], rows[3][2])
        return write_csv(tmp_path / "bad.csv", "t,u,y", rows)
    if kind == "non-uniform step":
        t = T.copy()
        t[100:] += 0.3 * DT
        return write_csv(tmp_path / "bad.csv", "t,u,y", [(repr(float(a)), b, c) for a, (_, b, c) in zip(t, rows)])
    if kind == "decreasing time":
        return write_csv(tmp_path / "bad.csv", "t,u,y", rows[::-1])
    if kind == "short row":
        rows[10] = rows[10][:2]
        return write_csv(tmp_path / "bad.csv", "t,u,y", rows)
    if kind == "too short":
        return write_csv(tmp_path / "bad.csv", "t,u,y", rows[:5])
    if kind == "empty file":
        (tmp_path / "bad.csv").write_text("")
        return tmp_path / "bad.csv"
    if kind == "header only":
        return write_csv(tmp_path / "bad.csv", "t,u,y", [])
    if kind == "npz length mismatch":
        np.savez(tmp_path / "bad.npz", t=T, u=U, y=Y[:-3])
        return tmp_path / "bad.npz"
    if kind == "npz missing array":
        np.savez(tmp_path / "bad.npz", t=T, u=U, x=Y)
        return tmp_path / "bad.npz"
    if kind == "npz nan":
        y = Y.copy()
        y[7] = np.nan
        np.savez(tmp_path / "bad.npz", t=T, u=U, y=y)
        return tmp_path / "bad.npz"
    if kind == "npz empty file":
        (tmp_path / "bad.npz").write_bytes(b"")
        return tmp_path / "bad.npz"
    if kind == "npz not a zip":
        (tmp_path / "bad.npz").write_text("t,u,y\n1,2,3\n")
        return tmp_path / "bad.npz"
    if kind == "unknown extension":
        return write_csv(tmp_path / "bad.dat", "t,u,y", rows)
    if kind == "missing file":
        return tmp_path / "does_not_exist.csv"
    raise AssertionError(kind)


BAD = {
    "missing column": "missing column(s) y",
    "nan": "column u",
    "empty field": "column y",
    "inf": "column t",
    "non-uniform step": "non-uniform time step",
    "decreasing time": "not increasing",
    "short row": "",
    "too short": "only 5 samples",
    "empty file": "missing column",
    "header only": "no data",
    "npz length mismatch": "length mismatch",
    "npz missing array": "missing array(s) y",
    "npz nan": "column y",
    "npz empty file": "",
    "npz not a zip": "",
    "unknown extension": "unsupported file type '.dat'",
    "missing file": "not found",
}


@pytest.mark.parametrize("kind", sorted(BAD))
def test_bad_file_gives_one_line_data_error_naming_the_file(tmp_path, registry, kind):
    path = _bad(tmp_path, kind)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # warnings are checked separately below
        with pytest.raises(DataError) as info:
            acquire(path, registry)
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert str(path) in msg, msg
    assert BAD[kind] in msg, msg
    assert info.value.exit_code == 2


@pytest.mark.parametrize("kind", sorted(BAD))
def test_bad_file_emits_no_python_warning(tmp_path, registry, kind):
    """A warning would print extra lines (file and source line) before mbus-run's one-line error."""
    path = _bad(tmp_path, kind)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(DataError):
            acquire(path, registry)
    assert [str(w.message) for w in caught] == []


def test_non_finite_value_reports_its_row(tmp_path, registry):
    path = _bad(tmp_path, "nan")
    with pytest.raises(DataError, match=r"1 non-finite or non-numeric value\(s\) \(first at row 41\)"):
        acquire(path, registry)


def test_non_uniform_step_reports_where(tmp_path, registry):
    path = _bad(tmp_path, "non-uniform step")
    with pytest.raises(DataError) as info:
        acquire(path, registry)
    assert "row 101" in str(info.value)


def test_tiny_jitter_is_accepted(tmp_path, registry):
    rng = np.random.default_rng(0)
    t = T + rng.uniform(-1e-8, 1e-8, N) * DT  # 1e-8 relative jitter, below the 1e-6 tolerance
    m = acquire(write_csv(tmp_path / "jit.csv", "t,u,y", [(repr(float(a)), b, c) for a, (_, b, c) in zip(t, good_rows())]), registry)
    assert len(m.t) == N
