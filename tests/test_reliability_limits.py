"""Issue 15, blow-ups: resource estimates before big allocations (checked against measured
peaks), bounded chain sizes, and numeric failures inside a fit as one-line errors."""
from __future__ import annotations

import os
import tracemalloc

import numpy as np
import pytest

from mbus_framework.errors import EstimationError
from mbus_framework.pipeline import limits
from mbus_framework.pipeline.run import execute
from reliability_support import assert_clean_outcome, config, file_backend, run_cli, write_tuy_csv, write_yaml


@pytest.mark.parametrize("n_elements, n_samples", [(3, 4000), (6, 2000)])
def test_memory_estimate_bounds_the_measured_peak_of_a_fit(tmp_path, n_elements, n_samples):
    cfg = config(model={"name": "kelvin_voigt", "options": {"n_elements": n_elements}},
                 excitation={"name": "prbs", "options": {"order": 7, "bit_width": 2.5e-6, "sample_rate": 2.0e6,
                                                         "n_samples": n_samples}})
    tracemalloc.start()
    try:
        outcome = execute(cfg, [], tmp_path / "out", plots=False, source="m.yaml")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    estimate = limits.fit_bytes(n_samples, outcome.components.model.n_states, 4 + 2)
    assert peak <= estimate, (peak, estimate)
    assert estimate - limits.FIT_OVERHEAD_BYTES <= 40 * peak  # an upper estimate, not a wild one


def test_a_record_too_big_for_the_memory_left_is_refused_before_anything_is_allocated(tmp_path, monkeypatch):
    monkeypatch.setattr(limits, "available_memory", lambda: 256 * 2**20)
    path = write_yaml(tmp_path / "big.yaml", config(excitation={"name": "prbs", "options": {
        "order": 9, "bit_width": 2.5e-6, "sample_rate": 2.0e6, "n_samples": 2_000_000}}))
    o = run_cli([path, "-o", tmp_path / "out"])
    assert o.code == 2
    assert_clean_outcome(o, ["excitation.options"])
    assert "2,000,000 samples with a 6-state model needs about 3.49 GiB" in o.err and "0.25 GiB available" in o.err
    assert not (tmp_path / "out").exists()


def test_a_data_file_too_big_to_fit_is_refused_after_reading(tmp_path, monkeypatch):
    monkeypatch.setattr(limits, "available_memory", lambda: limits.fit_bytes(100, 6, 6))
    data = write_tuy_csv(tmp_path)  # 200 samples; the configured excitation has 16
    cfg = config(backend=file_backend(data), excitation={"name": "prbs", "options": {
        "order": 5, "bit_width": 2.5e-6, "sample_rate": 2.0e6, "n_samples": 16}})
    o = run_cli([write_yaml(tmp_path / "f.yaml", cfg), "-o", tmp_path / "out"])
    assert o.code == 2
    assert "the record (saved; not fitted): a record of 200 samples" in o.err
    assert "estimation.decimate: " in o.err
    assert (tmp_path / "out" / "measurement.csv").is_file()  # nothing measured is lost


def test_two_million_samples_are_refused_by_the_default_memory_budget_naming_a_decimation(tmp_path):
    """Issue 24: a 2,000,000-sample record (a 20-state chain) needs more than the default 4 GiB:
    refused in one line naming the decimation that would fit: before the acquisition for a
    designed excitation (nothing is measured in vain), after saving it for a record read from
    a file (the test above)."""
    path = write_yaml(tmp_path / "big.yaml", config(
        model={"name": "kelvin_voigt", "options": {"n_elements": 10}},
        excitation={"name": "prbs", "options": {"order": 9, "bit_width": 0.4e-6, "sample_rate": 25.0e6,
                                                "n_samples": 2_000_000}}))
    o = run_cli([path, "-o", tmp_path / "out"])
    assert o.code == 2, o.err
    (line,) = [x for x in o.err.splitlines() if x.strip()]
    assert "estimation.max_memory_GiB of 4 GiB" in line and "estimation.decimate: " in line
    assert line.count("excitation.options") == 1


def test_available_memory_respects_the_address_space_limit():
    avail = limits.available_memory()
    assert avail is None or avail > 0


@pytest.mark.parametrize("model, options", [
    ("kelvin_voigt", {"n_elements": 200}),
    ("maxwell", {"n_elements": 101}),
    ("layered", {"layers": [{"n_elements": 60, "length": 0.02}, {"n_elements": 60}]}),
])
def test_chains_beyond_100_elements_are_refused_with_the_reason(tmp_path, model, options):
    path = write_yaml(tmp_path / "n.yaml", config(model={"name": model, "options": options}))
    o = run_cli([path, "-o", tmp_path / "out"])
    assert o.code == 2
    assert_clean_outcome(o, ["model.options"])
    assert "would take hours" in o.err and "Figs. 3.10-3.11" in o.err


def test_numeric_failure_inside_a_library_is_an_estimation_error(tmp_path, monkeypatch):
    from mbus_plugins.solvers.scipy_lm import ScipyLM

    def singular(self, problem, progress=None):
        np.linalg.cholesky(-np.eye(3))  # raises LinAlgError inside numpy

    monkeypatch.setattr(ScipyLM, "solve", singular)
    o = run_cli([write_yaml(tmp_path / "r.yaml", config()), "-o", tmp_path / "out"])
    assert o.code == 2
    assert_clean_outcome(o, ["solver scipy_lm"])
    assert "the fit failed numerically in numpy (LinAlgError: Matrix is not positive definite)" in o.err
    assert (tmp_path / "out" / "measurement.csv").is_file()


def test_the_same_exception_from_mbus_code_is_a_bug_not_an_estimation_error(tmp_path, monkeypatch):
    from mbus_plugins.solvers.scipy_lm import ScipyLM

    def buggy(self, problem, progress=None):
        raise ValueError("a bug in our own code")

    monkeypatch.setattr(ScipyLM, "solve", buggy)
    monkeypatch.setenv("MBUS_DEBUG", "1")
    with pytest.raises(ValueError, match="a bug in our own code"):
        execute(config(), [], tmp_path / "out", plots=False)


def test_estimation_errors_remember_what_they_converted(tmp_path, monkeypatch):
    from mbus_plugins.solvers.scipy_lm import ScipyLM

    monkeypatch.setattr(ScipyLM, "solve", lambda self, problem, progress=None: np.linalg.inv(np.zeros((2, 2))))
    with pytest.raises(EstimationError) as info:
        execute(config(), [], tmp_path / "out", plots=False)
    assert isinstance(info.value.converted_from, np.linalg.LinAlgError)


@pytest.mark.skipif(os.name != "posix", reason="POSIX resource limits")
def test_two_million_samples_under_an_address_space_limit_is_refused_at_once(tmp_path):
    """With 3 GiB of address space (ulimit -v), 2e6 samples stop before any allocation with the
    estimate, instead of a numpy allocation traceback a minute later."""
    import resource
    import subprocess

    from reliability_support import MBUS_RUN, python_env

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))

    path = write_yaml(tmp_path / "big.yaml", config(excitation={"name": "prbs", "options": {
        "order": 9, "bit_width": 2.5e-6, "sample_rate": 6.25e6, "n_samples": 2_000_000}}))
    p = subprocess.run([*MBUS_RUN, str(path), "-o", str(tmp_path / "out")], preexec_fn=limit, capture_output=True,
                       text=True, env=python_env(), timeout=120)
    assert p.returncode == 2, p.stderr[-2000:]
    (line,) = p.stderr.splitlines()
    assert "2,000,000 samples with a 6-state model needs about 3.49 GiB to fit, more than the" in line
    assert not (tmp_path / "out").exists()
