"""The example plugin package examples/fractional_kv: registration, contract, end-to-end runs.

Fast path: the package's module is registered in code (new_plugin_manager(extra_plugins=...))
and ``mbus-run`` (``cli.main``) runs with that registry. Slow path: the package is really
installed by pip (into a target folder put on PYTHONPATH, so the shared environment is not
changed) and ``mbus-run`` runs in a subprocess, finding it through its entry point.
"""
from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mbus_framework.interfaces import registry as registry_module
from mbus_framework.cli import main
from mbus_framework.plugins import Registry, Sample, new_plugin_manager
from mbus_framework.testing.models import MediumModelContract

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "fractional_kv"
CONFIG = EXAMPLE / "configs" / "fractional_kv.yaml"


@pytest.fixture(scope="module")
def fkv():
    sys.path.insert(0, str(EXAMPLE / "src"))
    try:
        yield importlib.import_module("mbus_fractional_kv")
    finally:
        sys.path.remove(str(EXAMPLE / "src"))


@pytest.fixture
def example_registry(fkv, monkeypatch):
    reg = Registry.from_manager(new_plugin_manager(extra_plugins=[("fractional_kv", fkv)]))
    monkeypatch.setattr(registry_module, "_default", reg)
    return reg


def test_listed_by_list_plugins(example_registry, capsys):
    assert main(["--list-plugins"]) == 0
    out = capsys.readouterr().out
    line = next(line for line in out.splitlines() if line.strip().startswith("fractional_kv"))
    assert "fractional Kelvin-Voigt" in line and "registered in code" in line


def test_runs_end_to_end_from_its_config(example_registry, tmp_path, capsys):
    out = tmp_path / "run"
    assert main([str(CONFIG), "-o", str(out), "--no-plots"]) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["model"]["name"] == "fractional_kv"
    truth = {"E_sigma": 2.2e9, "eta_alpha_sigma": 3.0e5, "E_tau": 4.0e8, "eta_tau": 2.0e3}
    for name, value in truth.items():
        assert result["properties"][name] == pytest.approx(value, rel=0.05), name
    assert "fractional_kv" in capsys.readouterr().out


def test_springpot_approximation(fkv):
    law = fkv.FractionalKelvinVoigtLaw(alpha=0.5, decades=2, arms_per_decade=2)
    k, c = 1e8, 1e5
    w_c = (k / c) ** 2
    w = w_c * np.logspace(-2, 2, 100)
    Z = law.impedance([k, c], 1j * w)
    exact = k + c * (1j * w) ** 0.5
    assert np.max(np.abs(Z - exact) / np.abs(exact)) < 2e-3
    assert np.all(law.w >= 0)  # positive arms: passive


class TestExampleContract(MediumModelContract):
    """The contract suite that the example's own tests run, here from the main test run."""

    model_name = "fractional_kv"

    @pytest.fixture(autouse=True)
    def _module(self, fkv):
        type(self).registry = Registry.from_manager(new_plugin_manager(extra_plugins=[("fractional_kv", fkv)]))
        self.fkv = fkv

    def make_models(self):
        s = Sample(length=0.02, diameter=0.0254, density=1000.0)
        o = self.fkv.FractionalKVOptions
        return [self.fkv.FractionalKelvinVoigtChain(s, o(n_elements=2, decades=1)),
                self.fkv.FractionalKelvinVoigtChain(s, o(n_elements=1, alpha=0.3, decades=1))]


@pytest.mark.slow
def test_pip_installed_package_is_found_and_runs(tmp_path):
    """pip-install the example (copied, so the source tree gets no build artefacts) into a
    target folder, then run the real ``mbus-run`` with it on PYTHONPATH."""
    src = tmp_path / "fractional_kv"
    shutil.copytree(EXAMPLE, src, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    target = tmp_path / "site"
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--target", str(target), str(src)],
                         capture_output=True, text=True, timeout=600)
    assert pip.returncode == 0, pip.stdout + pip.stderr
    assert list(target.glob("mbus_fractional_kv-*.dist-info"))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), str(ROOT)])}
    cli = [sys.executable, "-c", "import sys; from mbus_framework.cli import main; sys.exit(main(sys.argv[1:]))"]
    listed = subprocess.run(cli + ["--list-plugins"], capture_output=True, text=True, env=env, timeout=300)
    assert listed.returncode == 0, listed.stderr
    line = next(line for line in listed.stdout.splitlines() if line.strip().startswith("fractional_kv"))
    assert "mbus-fractional-kv 0.1.0" in line  # found through the installed entry point
    out = tmp_path / "run"
    run = subprocess.run(cli + [str(CONFIG), "-o", str(out), "--no-plots", "--quiet"], capture_output=True,
                         text=True, env=env, timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    result = json.loads((out / "result.json").read_text())
    assert result["model"]["name"] == "fractional_kv"
    assert result["properties"]["E_sigma"] == pytest.approx(2.2e9, rel=0.05)
    tests = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(src / "tests")],
                           capture_output=True, text=True, env=env, timeout=600, cwd=src)
    assert tests.returncode == 0, tests.stdout[-3000:]
