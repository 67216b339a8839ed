"""Issue 15, bad data files and bad data that looks good: every format is read with limits,
every problem is one line naming the right file, and result.json is strict JSON."""
from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mbus_framework.pipeline.storage import NON_FINITE_KEY, atomic_write_json, strict_json as to_strict_json
from reliability_support import (
    assert_clean_outcome,
    config,
    file_backend,
    run_cli,
    strict_json,
    write_gds_pair,
    write_lab_run,
    write_tuy_csv,
    write_tuy_npz,
    write_yaml,
)


def fit(tmp_path, backend, *extra):
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = write_yaml(tmp_path / "run.yaml", config(backend=backend))
    return run_cli([path, "-o", tmp_path / "out", *extra], timeout=60)


# -- t,u,y CSV in other encodings ----------------------------------------------------------
def test_latin1_header_and_utf16_export_are_read(tmp_path):
    original = write_tuy_csv(tmp_path)
    text = original.read_text()
    header, body = text.split("\n", 1)
    latin = tmp_path / "latin1.csv"
    latin.write_bytes((header + ",température\n").encode("latin-1")
                      + "".join(line + ",20\n" for line in body.splitlines()).encode("latin-1"))
    utf16 = tmp_path / "utf16.csv"
    utf16.write_bytes(text.replace("\n", "\r\n").encode("utf-16"))
    reference = fit(tmp_path / "a", file_backend(original))
    assert reference.code == 0, reference.err
    expected = strict_json(tmp_path / "a" / "out" / "result.json")["parameters"]
    for k, path in enumerate((latin, utf16)):
        o = fit(tmp_path / f"b{k}", file_backend(path))
        assert o.code == 0, o.err
        assert strict_json(tmp_path / f"b{k}" / "out" / "result.json")["parameters"] == pytest.approx(expected, rel=1e-9)


def test_utf16_bom_with_broken_body_is_one_line(tmp_path):
    path = tmp_path / "broken16.csv"
    path.write_bytes(b"\xff\xfe" + b"t\x00,\x00u\x00,\x00y\x00\n\x00\x00\xd8")  # lone surrogate
    o = fit(tmp_path, file_backend(path))
    assert o.code == 2
    assert_clean_outcome(o, [str(path)])


@pytest.mark.parametrize("value", ["1e308", "-1e308", "1e200"])
def test_huge_output_value_is_a_data_error_naming_the_file(tmp_path, value):
    path = write_tuy_csv(tmp_path)
    lines = path.read_text().splitlines()
    t, u, _ = lines[50].split(",")
    lines[50] = f"{t},{u},{value}"
    path.write_text("\n".join(lines) + "\n")
    o = fit(tmp_path, file_backend(path))
    assert o.code == 2
    assert_clean_outcome(o, [str(path)])
    assert "beyond 1e+100" in o.err


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs")
@pytest.mark.parametrize("name", ["record.csv", "record.npz", "A0001CH1.CSV"])
def test_fifo_as_data_file_fails_at_once(tmp_path, name):
    fifo = tmp_path / name
    os.mkfifo(fifo)
    o = fit(tmp_path, file_backend(fifo))
    assert o.code == 2
    assert_clean_outcome(o, [str(fifo)])
    assert "FIFO" in o.err


def test_npz_that_unpacks_to_gigabytes_is_refused_unread(tmp_path):
    """The archive's directory says 4 GB (as a zip bomb's does); nothing is unpacked to find out."""
    path = tmp_path / "bomb.npz"
    t, u, y = (np.arange(64.0) for _ in range(3))
    np.savez_compressed(path, t=t, u=u, y=y)
    raw = bytearray(path.read_bytes())
    central = raw.index(b"PK\x01\x02")  # first central-directory entry: uncompressed size at +24
    raw[central + 24:central + 28] = (0xFFFFFFF0).to_bytes(4, "little")
    path.write_bytes(bytes(raw))
    o = fit(tmp_path, file_backend(path))
    assert o.code == 2
    assert_clean_outcome(o, [str(path)])
    assert "unpacks to" in o.err


def test_npz_with_object_array_is_refused(tmp_path):
    path = tmp_path / "pickled.npz"
    np.savez(path, t=np.arange(20.0), u=np.array([object()] * 20, dtype=object), y=np.arange(20.0))
    o = fit(tmp_path, file_backend(path))
    assert o.code == 2
    assert_clean_outcome(o, [str(path)])


# -- GDS-2000 CSV exports ------------------------------------------------------------------
@pytest.mark.parametrize("row, fragment", [
    ("Memory Length,1e400,", "Memory Length"),
    ("Memory Length,inf,", "Memory Length"),
    ("Sampling Period,0,", "Sampling Period"),
    ("Sampling Period,1e-300,", "Sampling Period"),
])
def test_gds_header_values_are_checked(tmp_path, row, fragment):
    ch1, ch2 = write_gds_pair(tmp_path, "raw")
    key = row.split(",")[0]
    lines = [row if line.startswith(key + ",") else line for line in ch1.read_text(encoding="latin-1").splitlines()]
    ch1.write_text("\r\n".join(lines) + "\r\n", encoding="latin-1")
    o = fit(tmp_path, file_backend(ch1, response_path=str(ch2)))
    assert o.code == 2
    assert_clean_outcome(o, [str(ch1)])
    assert fragment in o.err and str(ch2) not in o.err


@pytest.mark.parametrize("layout", ["raw", "detail"])
@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_nan_in_the_response_file_is_reported_for_that_file(tmp_path, layout, bad):
    ch1, ch2 = write_gds_pair(tmp_path, layout)
    lines = ch2.read_text(encoding="latin-1").splitlines()
    i = len(lines) - 100
    lines[i] = (lines[i].split(",")[0] + "," + bad) if layout == "detail" else bad
    ch2.write_text("\r\n".join(lines) + "\r\n", encoding="latin-1")
    o = fit(tmp_path, file_backend(ch1, response_path=str(ch2)))
    assert o.code == 2
    assert_clean_outcome(o, [str(ch2)])
    assert f"{ch2}: line {i + 1}: non-finite value" in o.err
    assert str(ch1) not in o.err


# -- lab run folders -------------------------------------------------------------------------
def _rewrite_acquisition(folder, change):
    path = folder / "shots" / "acquisition.json"
    path.write_text(json.dumps(change(json.loads(path.read_text()))))
    return path


@pytest.mark.parametrize("change, fragment", [
    (lambda a: [a], "must be a JSON object, not list"),
    (lambda a: dict(a, processing=[1, 2]), "field 'processing' has the wrong type"),
    (lambda a: dict(a, processing={"u_gain": "x"}), "saved processing options are invalid"),
    (lambda a: dict(a, status=7), "field 'status' has the wrong type"),
    (lambda a: "just text", "must be a JSON object, not str"),
])
def test_lab_run_with_a_malformed_acquisition_record(tmp_path, change, fragment):
    folder = write_lab_run(tmp_path / "lab")
    path = _rewrite_acquisition(folder, change)
    o = fit(tmp_path, file_backend(folder))
    assert o.code == 2
    assert_clean_outcome(o, [str(path), str(folder / "shots")])
    assert fragment in o.err


@pytest.mark.parametrize("rate", [0.0, float("nan"), float("inf"), -5.0, 1e-300])
def test_lab_run_with_a_bad_generator_point_rate(tmp_path, rate):
    folder = write_lab_run(tmp_path / "lab")
    path = folder / "shots" / "excitation.npz"
    with np.load(path) as z:
        arrays = dict(z)
    arrays["points_rate_hz"] = np.float64(rate)
    np.savez(path, **arrays)
    o = fit(tmp_path, file_backend(folder))
    assert o.code == 2
    assert_clean_outcome(o, [str(path), str(folder / "shots")])


def test_partial_lab_acquisition_is_warned_in_result_json_and_the_summary(tmp_path):
    folder = write_lab_run(tmp_path / "lab", shots=2, status="failed", requested=4)
    o = fit(tmp_path, file_backend(folder))
    assert o.code == 0, o.err
    warning = "measurement: acquisition failed: 2 of 4 shots saved (GDS-2062: read CH1: short read (simulated))"
    result = strict_json(tmp_path / "out" / "result.json")
    assert result["warnings"][0] == warning
    summary = o.out.splitlines()
    assert summary[2] == f"  WARNING: {warning}"  # right under the title and the model, before any number
    assert sum(warning in line for line in summary) == 1


# -- strict JSON ---------------------------------------------------------------------------------
def test_non_finite_values_become_null_with_their_key_paths(tmp_path):
    path = atomic_write_json(tmp_path / "r.json", {
        "a": 1.0, "b": float("nan"), "c": {"d": [1.0, float("inf")], "e": -math.inf}, "f": np.float32("nan")})
    data = strict_json(path)
    assert data["b"] is None and data["c"]["d"] == [1.0, None] and data["c"]["e"] is None and data["f"] is None
    assert data[NON_FINITE_KEY] == {"b": "nan", "c.d[1]": "inf", "c.e": "-inf", "f": "nan"}


def test_finite_documents_carry_no_flag(tmp_path):
    assert NON_FINITE_KEY not in strict_json(atomic_write_json(tmp_path / "r.json", {"a": [1.0, 2]}))


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=5),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=4), children, max_size=4),
    max_leaves=25,
)


@given(st.dictionaries(st.text(max_size=4), json_values, max_size=6))
def test_strict_json_round_trip(doc):
    text = to_strict_json(doc)
    parsed = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard token {c}"))
    flags = parsed.pop(NON_FINITE_KEY, {})  # generated keys are at most 4 characters: no clash
    assert set(flags) == set(_non_finite_paths(doc))
    assert parsed == _strip(doc)


def _non_finite_paths(obj, where=""):
    if isinstance(obj, float) and not math.isfinite(obj):
        return [where or "(top level)"]
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in _non_finite_paths(v, f"{where}.{k}" if where else k)]
    if isinstance(obj, list):
        return [p for i, v in enumerate(obj) for p in _non_finite_paths(v, f"{where}[{i}]")]
    return []


def _strip(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def test_npz_record_reads_and_fits(tmp_path):
    o = fit(tmp_path, file_backend(write_tuy_npz(tmp_path)))
    assert o.code == 0, o.err
