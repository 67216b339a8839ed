"""A third-party medium model, written against ``mbus_framework`` only, is picked up BY NAME from a
config and fitted end to end without touching the core:

* registered in code on a fresh plugin manager (``new_plugin_manager(extra_plugins=...)``);
* installed as a distribution with an entry point in group ``mbus_framework`` and found by the
  ``mbus-run`` console script in a subprocess (``pip install --target`` into a private folder by
  default; ``pip install`` into the current environment, uninstalled afterwards, under ``-m slow``).
"""
from __future__ import annotations

import base64
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import textwrap
import types
import zipfile
from pathlib import Path

import numpy as np
import pytest

from mbus_framework.errors import ConfigError, PluginError
from mbus_framework.plugins import Registry, new_plugin_manager
from mbus_framework.pipeline.run import execute

# The plugin as its author would ship it: one module, imports from mbus_framework.plugins only.
PLUGIN_SOURCE = textwrap.dedent(
    '''
    """acme: a one-mass viscoelastic model (the whole column as one rigid mass on a Kelvin-Voigt link)."""
    from typing import Mapping

    import numpy as np
    from pydantic import BaseModel, ConfigDict, Field

    from mbus_framework.plugins import (MediumModel, MediumModelSpec, Parameter, Property, StateSpace, hookimpl,
                                        zeros_like_params)


    class OneMassOptions(BaseModel):
        model_config = ConfigDict(extra="forbid")
        mass_fraction: float = Field(1.0, gt=0, le=1, description="moving share of the column mass")


    class OneMass(MediumModel):
        """M x'' = u - k x - b x',  y = k x + b x',  M = mass_fraction * rho A L."""

        Options = OneMassOptions
        summary = "acme one-mass Kelvin-Voigt model (k, b)"

        @property
        def mass(self):
            return self.options.mass_fraction * self.sample.mass

        @property
        def parameters(self):
            s = self.sample
            return (
                Parameter("k", "N/m", "link stiffness", 0.0, np.inf, 2e9 * s.area / s.length, 2.0),
                Parameter("b", "N s/m", "link damping", 0.0, np.inf, 1e3 * s.area / s.length, 1.0),
            )

        @property
        def properties(self):
            return (Property("E", "Pa", "elastic modulus"), Property("eta", "Pa s", "viscosity"))

        def state_space(self, theta):
            k, b = theta[0], theta[1]
            A = zeros_like_params((2, 2), theta)
            A[0, 1] = 1.0
            A[1, 0] = -k / self.mass
            A[1, 1] = -b / self.mass
            B = zeros_like_params((2, 1), theta)
            B[1, 0] = 1.0 / self.mass
            C = zeros_like_params((1, 2), theta)
            C[0, 0] = k
            C[0, 1] = b
            return StateSpace(A, B, C, zeros_like_params((1, 1), theta))

        def to_properties(self, theta):
            f = self.sample.length / self.sample.area
            return {"E": f * float(theta[0]), "eta": f * float(theta[1])}

        def from_properties(self, properties: Mapping[str, float]):
            f = self.sample.length / self.sample.area
            return np.array([properties["E"] / f, properties["eta"] / f])


    @hookimpl
    def mbus_medium_models():
        return [MediumModelSpec("acme_one_mass", OneMass, OneMass.summary)]
    '''
)

MODULE_NAME = "acme_mbus_one_mass"
DIST_NAME = "acme-mbus-one-mass"

# Truth: E = 5e8 Pa, eta = 5e3 Pa s on a 2 cm column -> f0 ~ 5.6 kHz, damping ratio ~ 0.08.
L, D, RHO = 0.02, 0.0254, 1000.0
AREA = math.pi * D**2 / 4
TRUTH = {"k": 5e8 * AREA / L, "b": 5e3 * AREA / L}

CONFIG = f"""
title: third-party one-mass model
sample: {{length: {L}, diameter: {D}, density: {RHO}}}
model:
  name: acme_one_mass
  options: {{mass_fraction: 1.0}}
excitation:
  name: prbs
  options: {{order: 9, bit_width: 1.0e-5, sample_rate: 1.0e+6, n_samples: 2000}}
backend:
  name: simulated
  options:
    truth: {{k: {TRUTH["k"]!r}, b: {TRUTH["b"]!r}}}
    noise: {{relative_std: 0.02}}
    seed: 3
solver:
  name: scipy_lm
"""


def plugin_module() -> types.ModuleType:
    """The plugin as a module object, built from its source like an import would."""
    mod = types.ModuleType(MODULE_NAME)
    exec(compile(PLUGIN_SOURCE, f"<{MODULE_NAME}>", "exec"), mod.__dict__)
    return mod


@pytest.fixture
def config(tmp_path) -> Path:
    path = tmp_path / "one_mass.yaml"
    path.write_text(CONFIG)
    return path


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_manager(new_plugin_manager(extra_plugins=[("acme", plugin_module())]))


def test_registered_alongside_the_builtins(registry):
    entry = registry.entries["model"]["acme_one_mass"]
    assert entry.plugin == "acme" and entry.source == "registered in code"
    assert "kelvin_voigt" in registry.names("model")
    assert [b for b in registry.broken if b.name == "acme"] == []


def test_picked_up_by_name_from_a_config_and_fitted(config, registry, tmp_path):
    out = tmp_path / "out"
    outcome = execute(config, [], out, registry=registry, plots=False)
    r = json.loads((out / "result.json").read_text())
    assert r["model"]["name"] == "acme_one_mass"
    assert r["model"]["options"] == {"mass_fraction": 1.0}
    assert r["model"]["n_states"] == 2
    assert set(r["parameters"]) == {"k", "b"}
    assert r["parameter_units"] == {"k": "N/m", "b": "N s/m"}
    assert r["truth"] == pytest.approx(TRUTH, rel=1e-12)
    for name, value in TRUTH.items():
        assert r["parameters"][name] == pytest.approx(value, rel=0.02), name
    assert r["properties"]["E"] == pytest.approx(5e8, rel=0.02)
    assert r["properties"]["eta"] == pytest.approx(5e3, rel=0.05)
    assert r["solver"]["success"] is True
    assert r["fit"]["nrmse"] == pytest.approx(0.02, rel=0.15)  # the noise level: nothing left to fit
    assert (out / "measurement.csv").exists()
    assert type(outcome.components.model).__name__ == "OneMass"


def test_the_core_does_not_know_it_without_the_plugin(config, tmp_path):
    default = Registry.from_manager(new_plugin_manager())
    with pytest.raises(PluginError) as info:
        execute(config, [], tmp_path / "out", registry=default, plots=False)
    assert "unknown model 'acme_one_mass'" in str(info.value)


def test_its_options_are_validated_in_stage_two(config, registry, tmp_path):
    with pytest.raises(ConfigError) as info:
        execute(config, ["model.options.mass_fractoin=0.5"], tmp_path / "out", registry=registry, plots=False)
    assert "model.options.mass_fractoin: unknown key; did you mean 'mass_fraction'?" in str(info.value)
    with pytest.raises(ConfigError, match=r"model\.options\.mass_fraction: Input should be less than or equal to 1"):
        execute(config, ["model.options.mass_fraction=2"], tmp_path / "out", registry=registry, plots=False)
    with pytest.raises(ConfigError, match=r"model\.initial\.kk: .*did you mean 'k'"):
        execute(config, ["model.initial={kk: 1.0, b: 1.0}"], tmp_path / "out", registry=registry, plots=False)


def test_its_properties_work_as_truth_and_initial(config, registry, tmp_path):
    outcome = execute(
        config,
        ["backend.options.truth={E: 5.0e+8, eta: 5.0e+3}", "model.initial={E: 1.5e+9, eta: 1.0e+3}"],
        tmp_path / "out",
        registry=registry,
        plots=False,
    )
    assert outcome.result["strategy"]["initial_source"] == "config"
    assert outcome.result["properties"]["E"] == pytest.approx(5e8, rel=0.02)


def test_static_gain_of_the_plugin_model_is_one():
    """Sanity of the plugin itself (a third party's own test would do this)."""
    from mbus_framework.plugins import Sample

    mod = plugin_module()
    model = mod.OneMass(Sample(L, D, RHO), mod.OneMassOptions())
    A, B, C, Dm = model.state_space(np.array([TRUTH["k"], TRUTH["b"]]))
    assert float(Dm[0, 0] - (C @ np.linalg.solve(A, B))[0, 0]) == pytest.approx(1.0, abs=1e-12)


# ---------------------------------------------------------------------------------------
# As an installed distribution with an entry point
# ---------------------------------------------------------------------------------------
def build_wheel(folder: Path) -> Path:
    """A pure-Python wheel of the plugin with an entry point in group ``mbus_framework``.

    Written by hand (a wheel is a zip with a .dist-info folder): this environment's setuptools
    (65) cannot build wheels without the ``wheel`` package, and a test must not need the network
    for build isolation. The project sources are written next to it for reference.
    """
    src = folder / "src"
    src.mkdir(parents=True)
    (src / f"{MODULE_NAME}.py").write_text(PLUGIN_SOURCE)
    (src / "pyproject.toml").write_text(
        textwrap.dedent(
            f"""
            [build-system]
            requires = ["setuptools>=61"]
            build-backend = "setuptools.build_meta"

            [project]
            name = "{DIST_NAME}"
            version = "0.0.1"

            [project.entry-points.mbus_framework]
            acme = "{MODULE_NAME}"

            [tool.setuptools]
            py-modules = ["{MODULE_NAME}"]
            """
        )
    )
    dist_info = f"{DIST_NAME.replace('-', '_')}-0.0.1.dist-info"
    files = {
        f"{MODULE_NAME}.py": PLUGIN_SOURCE.encode(),
        f"{dist_info}/METADATA": f"Metadata-Version: 2.1\nName: {DIST_NAME}\nVersion: 0.0.1\n".encode(),
        f"{dist_info}/WHEEL": b"Wheel-Version: 1.0\nGenerator: mbus-tests\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
        f"{dist_info}/entry_points.txt": f"[mbus_framework]\nacme = {MODULE_NAME}\n".encode(),
    }
    record = []
    for name, data in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record.append(f"{name},sha256={digest},{len(data)}")
    record.append(f"{dist_info}/RECORD,,")
    files[f"{dist_info}/RECORD"] = ("\n".join(record) + "\n").encode()
    wheel = folder / f"{DIST_NAME.replace('-', '_')}-0.0.1-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return wheel


def pip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def mbus_run(*args: str, cwd: Path, extra_path: Path | None = None) -> subprocess.CompletedProcess:
    exe = shutil.which("mbus-run")
    if exe is None:
        pytest.skip("mbus-run console script not on PATH")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["CI"] = "1"
    if extra_path is not None:
        env["PYTHONPATH"] = str(extra_path)
    return subprocess.run([exe, *args], cwd=cwd, capture_output=True, text=True, timeout=300, env=env)


def check_listed_and_runs(tmp_path: Path, extra_path: Path | None):
    proc = mbus_run("--list-plugins", cwd=tmp_path, extra_path=extra_path)
    assert proc.returncode == 0, proc.stderr
    line = next((ln for ln in proc.stdout.splitlines() if ln.split()[:1] == ["acme_one_mass"]), None)
    assert line is not None, proc.stdout
    assert f"[{DIST_NAME} 0.0.1 [{MODULE_NAME}]]" in line
    broken = proc.stdout.partition("broken plugins (skipped):")[2]
    assert "acme" not in broken
    # ... and a config picks it up by name.
    cfg = tmp_path / "one_mass.yaml"
    cfg.write_text(CONFIG)
    proc = mbus_run(str(cfg), "-o", str(tmp_path / "out"), "--no-plots", "-q", cwd=tmp_path, extra_path=extra_path)
    assert proc.returncode == 0, proc.stderr
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert r["model"]["name"] == "acme_one_mass"
    assert r["parameters"]["k"] == pytest.approx(TRUTH["k"], rel=0.02)


def test_entry_point_distribution_on_a_private_path(tmp_path):
    """pip installs the wheel into a private folder; mbus-run finds it through PYTHONPATH.
    The shared environment is not modified."""
    wheel = build_wheel(tmp_path / "build")
    target = tmp_path / "site"
    proc = pip("install", "--no-deps", "--no-index", "--no-build-isolation", "--target", str(target), str(wheel))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (target / f"{MODULE_NAME}.py").exists()
    check_listed_and_runs(tmp_path, target)
    # Without the folder on the path the plugin is gone again.
    proc = mbus_run("--list-plugins", cwd=tmp_path)
    assert "acme_one_mass" not in proc.stdout


@pytest.mark.slow
def test_entry_point_distribution_installed_into_this_environment(tmp_path):
    """pip install into the running environment, run mbus-run, uninstall (teardown)."""
    if pip("show", DIST_NAME).returncode == 0:
        pytest.skip(f"{DIST_NAME} is already installed; not touching it")
    wheel = build_wheel(tmp_path / "build")
    proc = pip("install", "--no-deps", "--no-index", "--no-build-isolation", str(wheel))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    try:
        check_listed_and_runs(tmp_path, None)
    finally:
        done = pip("uninstall", "-y", DIST_NAME)
        assert done.returncode == 0, done.stdout + done.stderr
    assert pip("show", DIST_NAME).returncode != 0
