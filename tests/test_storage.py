"""Run-directory storage: atomic writes (no temp files left, old file kept on failure) and the
waveform CSV round trip through the ``file`` backend."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from mbus_framework.pipeline import storage
from mbus_framework.pipeline.storage import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_npz,
    atomic_write_text,
    to_jsonable,
    write_waveforms,
)
from mbus_plugins.backends.file import FileBackend, FileOptions, read_record


def listing(folder: Path) -> list[str]:
    """Every entry, hidden ones included (temp files start with a dot)."""
    return sorted(p.name for p in folder.iterdir())


def test_atomic_writes_leave_only_the_targets(tmp_path):
    atomic_write_bytes(tmp_path / "a.bin", b"\x00\x01")
    atomic_write_text(tmp_path / "b.txt", "h\u00e9llo\n")
    atomic_write_json(tmp_path / "c.json", {"x": np.float64(1.5), "n": np.int64(3), "v": np.arange(3)})
    atomic_write_npz(tmp_path / "d.npz", t=np.arange(4.0), y=np.ones(4))
    write_waveforms(tmp_path / "e.csv", np.arange(20) * 1e-6, np.ones(20), np.zeros(20))
    assert listing(tmp_path) == ["a.bin", "b.txt", "c.json", "d.npz", "e.csv"]
    assert (tmp_path / "a.bin").read_bytes() == b"\x00\x01"
    assert (tmp_path / "b.txt").read_text(encoding="utf-8") == "h\u00e9llo\n"
    assert json.loads((tmp_path / "c.json").read_text()) == {"x": 1.5, "n": 3, "v": [0, 1, 2]}
    with np.load(tmp_path / "d.npz") as z:
        np.testing.assert_array_equal(z["t"], np.arange(4.0))


def test_overwrite_replaces_content_and_creates_parents(tmp_path):
    target = tmp_path / "deep" / "er" / "f.txt"
    atomic_write_text(target, "one")
    atomic_write_text(target, "two")
    assert target.read_text() == "two"
    assert listing(target.parent) == ["f.txt"]


@pytest.mark.parametrize("fail_in", ["replace", "fsync", "write"])
def test_failed_write_keeps_the_old_file_and_removes_the_temp_file(tmp_path, monkeypatch, fail_in):
    target = tmp_path / "result.json"
    atomic_write_json(target, {"version": 1})

    def boom(*args, **kwargs):
        raise OSError("disk full (simulated)")

    if fail_in == "replace":
        monkeypatch.setattr(storage.os, "replace", boom)
    elif fail_in == "fsync":
        monkeypatch.setattr(storage.os, "fsync", boom)
    else:
        real_fdopen = os.fdopen

        class Failing:
            def __init__(self, fh):
                self.fh = fh

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                self.fh.close()
                return False

            def write(self, data):
                self.fh.write(data[: len(data) // 2])
                raise OSError("disk full (simulated)")

        monkeypatch.setattr(storage.os, "fdopen", lambda fd, mode: Failing(real_fdopen(fd, mode)))
    with pytest.raises(OSError, match="simulated"):
        atomic_write_json(target, {"version": 2, "payload": list(range(1000))})
    monkeypatch.undo()
    assert listing(tmp_path) == ["result.json"]
    assert json.loads(target.read_text()) == {"version": 1}


def test_unserialisable_json_fails_before_touching_the_file(tmp_path):
    target = tmp_path / "r.json"
    atomic_write_json(target, {"ok": True})
    with pytest.raises(TypeError):
        atomic_write_json(target, {"bad": object()})
    assert json.loads(target.read_text()) == {"ok": True}
    assert listing(tmp_path) == ["r.json"]


def test_to_jsonable_converts_numpy_recursively(tmp_path):
    obj = {
        1: np.float32(0.5),
        "a": (np.int32(2), np.bool_(True)),
        "b": {"c": np.array([[1.0, 2.0]]), "p": tmp_path},
        "nan": float("nan"),
    }
    out = to_jsonable(obj)
    assert out["1"] == 0.5 and type(out["1"]) is float
    assert out["a"] == [2, True] and type(out["a"][0]) is int and type(out["a"][1]) is bool
    assert out["b"] == {"c": [[1.0, 2.0]], "p": str(tmp_path)}
    text = json.dumps(out, allow_nan=True)
    assert "NaN" in text


def test_waveform_csv_round_trip_is_exact_through_the_file_backend(tmp_path):
    rng = np.random.default_rng(3)
    dt = 1.0 / 6.25e6
    t = np.arange(3000) * dt
    u = rng.choice([-1.0, 1.0], 3000)
    y = rng.normal(0.0, 1e-3, 3000) * np.exp(-t / 1e-4) + 1e-12 * rng.normal(size=3000)
    path = write_waveforms(tmp_path / "measurement.csv", t, u, y)
    assert path.read_text().splitlines()[0] == "t,u,y"
    m = read_record(path)
    np.testing.assert_array_equal(m.u, u)
    np.testing.assert_array_equal(m.y, y)  # %.17g keeps every bit
    np.testing.assert_allclose(m.t, t, rtol=0, atol=1e-20)
    assert m.dt == pytest.approx(dt, rel=1e-12)
    # The plugin, as a run uses it.
    m2 = FileBackend(FileOptions(path=str(path))).acquire(None)
    np.testing.assert_array_equal(m2.y, y)
    assert m2.meta["source"] == str(path)


def test_npz_round_trip_through_the_file_backend(tmp_path):
    t = np.arange(64) * 1e-7
    u, y = np.sin(t * 1e6), np.cos(t * 1e6)
    atomic_write_npz(tmp_path / "rec.npz", t=t, u=u, y=y)
    m = read_record(tmp_path / "rec.npz")
    np.testing.assert_array_equal(m.u, u)
    np.testing.assert_array_equal(m.y, y)


@pytest.mark.parametrize("dtype", [float, np.float32, np.int64])
def test_waveform_csv_is_the_text_of_numpy_savetxt(tmp_path, dtype):
    """write_waveforms formats in one operation; the text is np.savetxt's, special values included."""
    import io

    rng = np.random.default_rng(3)
    t, u, y = np.arange(500) * 4e-8, rng.normal(size=500) * 1e3, rng.normal(size=500) * 1e-9
    if dtype is float:
        u[[1, 2, 3]] = [np.nan, np.inf, -np.inf]
        y[[4, 5, 6]] = [-0.0, 5e-324, 1.7976931348623157e308]
    data = [np.asarray(a * (1e9 if dtype is np.int64 else 1)).astype(dtype) for a in (t, u, y)]
    expected = io.StringIO()
    np.savetxt(expected, np.column_stack(data), delimiter=",", header="t,u,y", comments="", fmt="%.17g")
    write_waveforms(tmp_path / "m.csv", *data)
    assert (tmp_path / "m.csv").read_text() == expected.getvalue()
