"""One path rule: a config file's relative paths are taken from its folder, ``--set`` ones from
the working directory; a missing file names the key, the value and where it was looked for."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from mbus_framework.cli import main
from mbus_framework.errors import DataError
from mbus_framework.pipeline.config import load_config

REPO = Path(__file__).resolve().parents[1]
POTATO = REPO / "examples" / "recorded" / "potato_tuy.csv"


def config(folder: Path, **sections) -> Path:
    data = {"sample": {"length": 0.03, "diameter": 0.0254, "density": 1080.0},
            "model": {"name": "kelvin_voigt", "options": {"n_elements": 10}},
            "backend": {"name": "file", "options": {"path": "data/rec.csv"}},
            "solver": {"name": "scipy_lm"}, **sections}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "run.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture()
def layout(tmp_path, monkeypatch):
    """A config folder with data/rec.csv, and a working directory holding a *different* rec."""
    cfg = config(tmp_path / "cfgdir")
    (tmp_path / "cfgdir" / "data").mkdir()
    shutil.copy(POTATO, tmp_path / "cfgdir" / "data" / "rec.csv")
    cwd = tmp_path / "cwd"
    (cwd / "data").mkdir(parents=True)
    (cwd / "data" / "rec.csv").write_text("t,u,y\n" + "".join(f"{k}e-6,1,0\n" for k in range(20)))
    monkeypatch.chdir(cwd)
    return cfg


def test_file_paths_are_relative_to_the_config_not_the_working_directory(layout):
    c = load_config(layout)
    assert c.backend.options["path"] == str(layout.parent / "data" / "rec.csv")


def test_set_paths_are_relative_to_the_working_directory(layout):
    c = load_config(layout, ["backend.options.path=data/rec.csv"])  # unchanged value: still the file's
    assert c.backend.options["path"] == str(layout.parent / "data" / "rec.csv")
    c = load_config(layout, ["backend.options.path=./data/rec.csv"])
    assert c.backend.options["path"] == str(Path.cwd() / "data" / "rec.csv")


@pytest.mark.parametrize("key, section, what", [
    ("backend.options.path", None, "file"),
    ("compensator.options.calibration",
     {"compensator": {"name": "transfer_function", "options": {"calibration": "cal/pair.npz"}}}, "calibration file"),
    ("excitation.options.path", {"excitation": {"name": "from_file", "options": {"path": "wave.csv"}}}, "waveform file"),
])
def test_a_missing_input_names_the_key_the_value_and_the_place_searched(tmp_path, monkeypatch, key, section, what):
    cfg = config(tmp_path / "c", **(section or {}))
    if section:  # the data is there; the other file is not
        (tmp_path / "c" / "data").mkdir()
        shutil.copy(POTATO, tmp_path / "c" / "data" / "rec.csv")
    monkeypatch.chdir(tmp_path)
    value = {"backend.options.path": "data/rec.csv", "compensator.options.calibration": "cal/pair.npz",
             "excitation.options.path": "wave.csv"}[key]
    with pytest.raises(DataError) as err:
        load_config(cfg, check_files=True)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"{cfg}: {key} = '{value}': {tmp_path / 'c' / value}: {what} not found")
    assert f"taken from the config file's folder, {tmp_path / 'c'}" in msg


def test_calibration_and_waveform_paths_resolve_next_to_the_config(tmp_path, monkeypatch):
    (tmp_path / "c" / "cal").mkdir(parents=True)
    (tmp_path / "c" / "cal" / "pair.npz").write_bytes(b"x")
    (tmp_path / "c" / "wave.csv").write_text("0\n1\n")
    (tmp_path / "c" / "data").mkdir()
    shutil.copy(POTATO, tmp_path / "c" / "data" / "rec.csv")
    cfg = config(tmp_path / "c", compensator={"name": "transfer_function", "options": {"calibration": "cal/pair.npz"}},
                 excitation={"name": "from_file", "options": {"path": "wave.csv"}})
    monkeypatch.chdir(tmp_path)
    c = load_config(cfg, check_files=True)
    assert c.compensator.options["calibration"] == str(tmp_path / "c" / "cal" / "pair.npz")
    assert c.excitation.options["path"] == str(tmp_path / "c" / "wave.csv")


def test_the_calibration_output_is_written_next_to_the_config():
    c = load_config(REPO / "configs" / "water_calibration.yaml")
    raw = c.model_dump(mode="json")
    assert raw["calibration"]["output"] == str(REPO / "configs" / "calibrations" / "virtual_a301s.npz")


def test_a_run_folders_config_reruns_from_another_directory(layout, tmp_path, monkeypatch, capsys):
    """Issue 27 item 1: the run folder's config.yaml holds absolute paths."""
    assert main([str(layout), "-o", str(tmp_path / "first"), "--no-plots", "--quiet"]) == 0
    first = json.loads((tmp_path / "first" / "result.json").read_text())
    saved = yaml.safe_load((tmp_path / "first" / "config.yaml").read_text())
    assert saved["backend"]["options"]["path"] == str(layout.parent / "data" / "rec.csv")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main([str(tmp_path / "first" / "config.yaml"), "-o", str(tmp_path / "second"), "--no-plots", "--quiet"]) == 0
    second = json.loads((tmp_path / "second" / "result.json").read_text())
    for name, value in first["properties"].items():
        assert second["properties"][name] == pytest.approx(value, rel=1e-9), name
    assert np.isclose(first["properties"]["E_sigma"], 2.42e10, rtol=0.01)
