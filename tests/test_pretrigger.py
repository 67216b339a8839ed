"""Pre-trigger samples and DC offsets of t,u,y files are found, removed, recorded and reported."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

import mbus_framework as mbus
from mbus_framework.cli import main

REPO = Path(__file__).resolve().parents[1]
POTATO = REPO / "examples" / "recorded" / "potato_tuy.csv"
SAMPLE = {"length": 0.03, "diameter": 0.0254, "density": 1080.0}
PRE, OFFSET = 200, 0.01


def shifted(tmp_path: Path, pre=PRE, offset=OFFSET, u_offset=0.0) -> Path:
    """The shipped potato record with ``pre`` recorded samples before the burst (rest plus the
    record's own noise level) and a constant offset on y (and u)."""
    data = np.loadtxt(POTATO, delimiter=",", skiprows=1)
    t, u, y = data.T
    dt = t[1] - t[0]
    noise = 0.03 * np.std(y) * np.random.default_rng(3).standard_normal(pre)
    t2 = np.concatenate([np.arange(pre) * dt, pre * dt + t])
    u2 = np.concatenate([np.zeros(pre), u]) + u_offset
    y2 = np.concatenate([noise, y]) + offset
    path = tmp_path / "late.csv"
    np.savetxt(path, np.column_stack([t2, u2, y2]), delimiter=",", header="t,u,y", comments="", fmt="%.9g")
    return path


def test_pretrigger_is_cut_at_the_onset_and_offsets_are_measured(tmp_path):
    clean = mbus.load_record(POTATO)
    record = mbus.load_record(shifted(tmp_path, u_offset=-0.02))
    p = record.meta["pretrigger"]
    assert p["samples"] == PRE and p["seconds"] == pytest.approx(PRE * 4e-8)
    assert p["offset_y"] == pytest.approx(OFFSET, abs=3 * 0.03 * np.std(clean.y) / np.sqrt(PRE))
    assert p["offset_u"] == pytest.approx(-0.02, abs=1e-9)
    np.testing.assert_allclose(record.u, clean.u, atol=2e-9)
    assert record.u.size == clean.u.size
    np.testing.assert_allclose(record.y, clean.y + OFFSET - p["offset_y"], atol=1e-8)
    raw = mbus.load_record(shifted(tmp_path), pretrigger=False)  # opt-out: the file as it is
    assert raw.u.size == clean.u.size + PRE and "pretrigger" not in raw.meta


def test_a_record_that_starts_at_the_burst_is_unchanged():
    record = mbus.load_record(POTATO)
    assert record.meta["pretrigger"]["samples"] == 0
    np.testing.assert_array_equal(record.y, np.loadtxt(POTATO, delimiter=",", skiprows=1)[:, 2])


def test_offset_and_pretrigger_fit_as_well_as_the_clean_record(tmp_path):
    """Issue 27: with 200 pre-trigger samples and +0.01 on y the fit was 5x worse (nrmse 0.163)."""
    clean = mbus.fit(*mbus.load_record(POTATO), sample=SAMPLE)
    late = mbus.fit(*mbus.load_record(shifted(tmp_path)), sample=SAMPLE)
    assert late.fit_quality["nrmse"] <= 1.2 * clean.fit_quality["nrmse"], (late.fit_quality, clean.fit_quality)
    for name, p in clean.properties.items():
        assert late.properties[name].value == pytest.approx(p.value, rel=0.02), name


def test_the_run_reports_what_was_removed(tmp_path, capsys):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(yaml.safe_dump({
        "sample": SAMPLE, "model": {"name": "kelvin_voigt", "options": {"n_elements": 10}},
        "backend": {"name": "file", "options": {"path": str(shifted(tmp_path))}},
        "solver": {"name": "scipy_lm"}}))
    assert main([str(cfg), "-o", str(tmp_path / "out"), "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "record: 200 pre-trigger samples (8e-06 s) cut before the onset; offsets removed: u 0, y 0.01" in out
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["pretrigger"]["samples"] == PRE
    saved = json.loads((tmp_path / "out" / "measurement.json").read_text())
    assert saved["meta"]["pretrigger"]["offset_y"] == pytest.approx(OFFSET, abs=1e-3)
