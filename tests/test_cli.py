"""``mbus-run`` end to end: the shipped configs meet the issue's accuracy, result.json has its
schema, data are saved before estimation, and user errors are one line with exit status 2 (3 for
instruments), never a traceback."""
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from mbus_framework.cli import main
from mbus_framework.errors import EstimationError, InstrumentError

REPO = Path(__file__).resolve().parents[1]
POTATO = REPO / "configs" / "potato.yaml"
TABLE = REPO / "configs" / "table3_1.yaml"
SET_2 = "model.initial={k_sigma: 1.95e8, b_sigma: 7.5, k_tau: 3.25e7, b_tau: 6.0}"
TABLE_TRUTH = {"k_sigma": 3.0e8, "b_sigma": 15.0, "k_tau": 5.0e7, "b_tau": 12.0}


def potato_truth() -> dict[str, float]:
    """Table 6.2 properties -> KV parameters by eqs. 3.32-3.38 (L 0.03 m, D 25.4 mm, n 10)."""
    L, D, n = 0.03, 0.0254, 10
    area = math.pi * D**2 / 4
    return {
        "k_sigma": 2.42e10 * area / (L / n),
        "b_sigma": 7.18e3 * area / (L / n),
        "k_tau": 6.56e9 * math.pi * D,
        "b_tau": 5.14e3 * math.pi * D,
    }


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def result(out_dir: Path) -> dict:
    return json.loads((out_dir / "result.json").read_text())


def assert_user_error(code: int, err: str, expected_code: int = 2, fragment: str = ""):
    assert code == expected_code
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("mbus-run: error: ")
    assert "Traceback" not in err
    assert fragment in lines[0], lines[0]


# ---------------------------------------------------------------------------------------
# The shipped configs
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def potato_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("potato") / "run"
    code = main([str(POTATO), "-o", str(out)])
    return code, out


def test_potato_recovers_every_parameter_within_2_percent(potato_run):
    code, out = potato_run
    assert code == 0
    r = result(out)
    truth = potato_truth()
    assert r["truth"] == pytest.approx(truth, rel=1e-12)
    for name, value in truth.items():
        assert r["parameters"][name] == pytest.approx(value, rel=0.02), name
    props = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}
    for name, value in props.items():
        assert r["properties"][name] == pytest.approx(value, rel=0.02), name


def test_result_json_schema(potato_run):
    _, out = potato_run
    r = result(out)
    names = ["k_sigma", "b_sigma", "k_tau", "b_tau"]
    assert list(r["parameters"]) == names
    assert set(r["properties"]) == {"E_sigma", "eta_sigma", "E_tau", "eta_tau"}
    assert list(r["truth"]) == names
    assert all(isinstance(v, float) and v > 0 for v in r["parameters"].values())
    assert set(r["fit"]) >= {"mse", "nrmse"}
    assert isinstance(r["fit"]["mse"], float) and r["fit"]["mse"] > 0
    # nrmse = sqrt(mse) / RMS(y), and the fit leaves just the 3 % noise.
    y = np.loadtxt(out / "measurement.csv", delimiter=",", skiprows=1)[:, 2]
    assert r["fit"]["nrmse"] == pytest.approx(math.sqrt(r["fit"]["mse"]) / math.sqrt(np.mean(y**2)), rel=1e-9)
    assert r["fit"]["nrmse"] == pytest.approx(0.03, rel=0.1)
    solver = r["solver"]
    assert set(solver) >= {"name", "success", "status", "message", "nfev", "wall_time_s"}
    assert solver["name"] == "scipy_lm"
    assert solver["success"] is True
    assert isinstance(solver["status"], int) and solver["status"] > 0
    assert isinstance(solver["message"], str) and solver["message"]
    assert isinstance(solver["nfev"], int) and solver["nfev"] > 0
    assert isinstance(solver["wall_time_s"], float) and solver["wall_time_s"] > 0


def test_run_folder_contents(potato_run):
    _, out = potato_run
    for name in ("measurement.csv", "measurement.json", "result.json", "fit.svg", "config.yaml"):
        assert (out / name).is_file(), name
    assert (out / "fit.svg").read_bytes()[:5] == b"<svg "
    data = np.loadtxt(out / "measurement.csv", delimiter=",", skiprows=1)
    assert (out / "measurement.csv").read_text().splitlines()[0] == "t,u,y"
    assert data.shape == (5000, 3)
    assert np.diff(data[:, 0]) == pytest.approx(np.full(4999, 1 / 25e6), rel=1e-9)
    assert set(np.unique(data[:, 1])) == {-1.0, 1.0}
    meta = json.loads((out / "measurement.json").read_text())
    assert meta["n_samples"] == 5000
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")], "temporary files left behind"


def test_summary_is_readable(potato_run):
    """What mbus-run prints: parameters and properties with units, fit quality, solver, truth."""
    from mbus_framework.pipeline.report import summary_text

    _, out = potato_run
    text = summary_text(result(out), out)
    for word in ("k_sigma", "E_sigma", "Pa s", "N/m", "nrmse", "scipy_lm", "truth", str(out)):
        assert word in text


@pytest.fixture(scope="module")
def table_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("table3_1")
    runs = {}
    for label, overrides in (("set1", []), ("set2", ["--set", SET_2])):
        out = base / label
        assert main([str(TABLE), "-o", str(out), "--no-plots", "-q", *overrides]) == 0
        runs[label] = result(out)
        runs[label]["_dir"] = out
    return runs


def test_table_3_1_both_initial_sets_reach_the_same_minimum(table_runs):
    a, b = table_runs["set1"]["parameters"], table_runs["set2"]["parameters"]
    for name in TABLE_TRUTH:
        assert a[name] == pytest.approx(b[name], rel=1e-4), name
    assert table_runs["set1"]["strategy"]["initial"] == pytest.approx({"k_sigma": 6e8, "b_sigma": 37.5, "k_tau": 1e8, "b_tau": 30.0})
    assert table_runs["set2"]["strategy"]["initial"] == pytest.approx({"k_sigma": 1.95e8, "b_sigma": 7.5, "k_tau": 3.25e7, "b_tau": 6.0})


@pytest.mark.parametrize("label", ["set1", "set2"])
def test_table_3_1_accuracy(table_runs, label):
    r = table_runs[label]
    assert r["truth"] == pytest.approx(TABLE_TRUTH)
    p = r["parameters"]
    assert p["k_sigma"] == pytest.approx(3.0e8, rel=0.01)
    assert p["k_tau"] == pytest.approx(5.0e7, rel=0.01)
    assert p["b_sigma"] == pytest.approx(15.0, rel=0.02)
    assert p["b_tau"] == pytest.approx(12.0, rel=0.02)
    assert r["fit"]["nrmse"] == pytest.approx(0.10, rel=0.1)
    assert r["excitation"]["name"] == "prbs"
    assert (r["_dir"] / "measurement.csv").is_file()
    assert not list(r["_dir"].glob("*.png"))  # --no-plots


# ---------------------------------------------------------------------------------------
# Data first: the measurement survives a failing estimator
# ---------------------------------------------------------------------------------------
def small_config(tmp_path: Path, **backend) -> Path:
    backend_text = json.dumps(
        backend
        or {
            "name": "simulated",
            "options": {"truth": {"E_sigma": 3e9, "eta_sigma": 300.0, "E_tau": 5e8, "eta_tau": 400.0}, "seed": 2},
        }
    )
    path = tmp_path / "small.yaml"
    path.write_text(
        "title: small\n"
        "sample: {length: 0.02, diameter: 0.0254, density: 1050.0}\n"
        "model: {name: kelvin_voigt, options: {n_elements: 4}}\n"
        "excitation: {name: prbs, options: {order: 9, bit_width: 1.0e-6, sample_rate: 1.0e+7, n_samples: 1500}}\n"
        f"backend: {backend_text}\n"
    )
    return path


def test_measurement_is_written_even_when_the_solver_raises(tmp_path, capsys, monkeypatch):
    from mbus_plugins.solvers.scipy_lm import ScipyLM

    seen = {}

    def exploding_solve(self, problem, progress=None):
        out = tmp_path / "out"
        seen["csv_before_solve"] = (out / "measurement.csv").is_file()
        seen["y"] = problem.y.copy()
        raise EstimationError("simulated solver failure")

    monkeypatch.setattr(ScipyLM, "solve", exploding_solve)
    code, out, err = run(capsys, small_config(tmp_path), "-o", tmp_path / "out")
    assert_user_error(code, err, 2, "simulated solver failure")
    assert seen["csv_before_solve"] is True
    data = np.loadtxt(tmp_path / "out" / "measurement.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(data[:, 2], seen["y"])
    assert (tmp_path / "out" / "measurement.json").is_file()
    assert not (tmp_path / "out" / "result.json").exists()


def test_measurement_is_written_even_when_the_solver_crashes(tmp_path, monkeypatch):
    """A bug in a solver (not a user error) propagates, but the data are already on disk."""
    from mbus_plugins.solvers.scipy_lm import ScipyLM

    def crashing_solve(self, problem, progress=None):
        raise ZeroDivisionError("bug")

    monkeypatch.setattr(ScipyLM, "solve", crashing_solve)
    monkeypatch.setenv("MBUS_DEBUG", "1")  # without it mbus-run reports the bug in one line (exit 70)
    with pytest.raises(ZeroDivisionError):
        main([str(small_config(tmp_path)), "-o", str(tmp_path / "out")])
    assert (tmp_path / "out" / "measurement.csv").is_file()


def test_interrupt_exits_130_with_the_data_saved(tmp_path, capsys, monkeypatch):
    from mbus_plugins.solvers.scipy_lm import ScipyLM

    def interrupted(self, problem, progress=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(ScipyLM, "solve", interrupted)
    code, out, err = run(capsys, small_config(tmp_path), "-o", tmp_path / "out")
    assert code == 130
    assert err.strip() == "mbus-run: interrupted"
    assert (tmp_path / "out" / "measurement.csv").is_file()


def test_an_interrupted_import_is_an_interruption_not_a_bug(tmp_path, capsys, monkeypatch):
    """Ctrl-C while a compiled module initialises surfaces as ``ImportError: initialization
    failed`` (its cause the KeyboardInterrupt): exit 130, not an internal error (70)."""
    import mbus_framework.cli as cli

    def interrupted_import(data):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    monkeypatch.setattr(cli, "_config_kind", interrupted_import)
    code, out, err = run(capsys, small_config(tmp_path), "-o", tmp_path / "out")
    assert (code, err.strip()) == (130, "mbus-run: interrupted")
    monkeypatch.setattr(cli, "_config_kind", lambda data: 1 / 0)  # a real bug is still one
    code, out, err = run(capsys, small_config(tmp_path), "-o", tmp_path / "out")
    assert code == 70 and "internal error: ZeroDivisionError" in err


def test_the_config_yaml_is_read_once_before_validation(tmp_path, capsys, monkeypatch):
    """The PNG-figure check and the campaign/substitution/joint check share one read of the file."""
    from mbus_framework.pipeline import config as config_module

    reads = []
    real = config_module.config_mapping_or_none
    monkeypatch.setattr(config_module, "config_mapping_or_none", lambda path: reads.append(path) or real(path))
    path = small_config(tmp_path)
    code, out, err = run(capsys, path, "-o", tmp_path / "out", "--set", "output.plots=false", "-q")
    assert (code, err) == (0, "")
    assert reads == [str(path)]


def test_instrument_error_exits_3(tmp_path, capsys, monkeypatch):
    from mbus_plugins.backends.simulated import SimulatedBackend

    def failing_acquire(self, context):
        raise InstrumentError("DS340 on /dev/ttyUSB0: no reply to *IDN?")

    monkeypatch.setattr(SimulatedBackend, "acquire", failing_acquire)
    code, out, err = run(capsys, small_config(tmp_path), "-o", tmp_path / "out")
    assert_user_error(code, err, 3, "DS340")


# ---------------------------------------------------------------------------------------
# Bad input: exit 2, one line, no traceback
# ---------------------------------------------------------------------------------------
BAD_CONFIGS = {
    "missing file": (None, [], "config file not found"),
    "yaml syntax": ("sample: [1, 2\nmodel: x\n", [], "invalid YAML at line"),
    "python tag": ("sample: !!python/object/apply:os.getcwd []\n", [], "invalid YAML"),
    "empty": ("", [], "empty"),
    "not a mapping": ("- 1\n- 2\n", [], "top level must be a mapping"),
    "unknown key": ("SMALL", ["sample.lenght=1"], "did you mean 'length'"),
    "bad value": ("SMALL", ["sample.length=-1"], "sample.length"),
    "unknown plugin": ("SMALL", ["model.name=kelvin_voight"], "did you mean 'kelvin_voigt'"),
    "plugin option": ("SMALL", ["model.options.n_element=3"], "model.options.n_element"),
    "bad --set": ("SMALL", ["sample.length"], "expected dotted.key=value"),
    "unknown initial": ("SMALL", ["model.initial={k_sigmaa: 1, b_sigma: 1, k_tau: 1, b_tau: 1}"], "model.initial.k_sigmaa"),
    "unknown truth": ("SMALL", ["backend.options.truth.E_sigmaa=1"], "backend.options.truth.E_sigmaa"),
}


@pytest.mark.parametrize("case", sorted(BAD_CONFIGS))
def test_bad_config_is_one_line_exit_2(case, tmp_path, capsys):
    text, overrides, fragment = BAD_CONFIGS[case]
    if text == "SMALL":
        path = small_config(tmp_path)
    else:
        path = tmp_path / "bad.yaml"
        if text is not None:
            path.write_text(text)
    argv = [path, "-o", tmp_path / "out", "--no-plots"]
    for o in overrides:
        argv += ["--set", o]
    code, out, err = run(capsys, *argv)
    assert_user_error(code, err, 2, fragment)


@pytest.mark.parametrize(
    "content, fragment",
    [
        (None, "file not found"),
        ("t,u\n0,1\n", "missing column(s) y"),
        ("t,u,y\n" + "".join(f"{k * 1e-7},1,{'nan' if k == 5 else 0.5}\n" for k in range(50)), "non-finite"),
    ],
)
def test_bad_data_path_is_one_line_exit_2(tmp_path, capsys, content, fragment):
    data = tmp_path / "rec.csv"
    if content is not None:
        data.write_text(content)
    cfg = small_config(tmp_path, name="file", options={"path": str(data)})
    code, out, err = run(capsys, cfg, "-o", tmp_path / "out")
    assert_user_error(code, err, 2, fragment)
    assert str(data) in err


def test_fit_from_a_recorded_file(tmp_path, capsys):
    """Data first, in practice: re-fit the measurement.csv a simulated run saved, via the file backend."""
    first = tmp_path / "first"
    assert main([str(small_config(tmp_path)), "-o", str(first), "--no-plots", "-q"]) == 0
    capsys.readouterr()
    cfg = small_config(tmp_path, name="file", options={"path": str(first / "measurement.csv")})
    code, out, err = run(capsys, cfg, "-o", tmp_path / "second", "--no-plots", "-q")
    assert code == 0, err
    a, b = result(first), result(tmp_path / "second")
    for name in a["parameters"]:
        assert b["parameters"][name] == pytest.approx(a["parameters"][name], rel=1e-6)
    assert "truth" not in b


# ---------------------------------------------------------------------------------------
# Output options
# ---------------------------------------------------------------------------------------
def test_quiet_prints_only_the_output_folder(tmp_path, capsys):
    code, out, err = run(capsys, small_config(tmp_path), "-o", tmp_path / "q", "--quiet")
    assert code == 0
    assert out.strip() == str(tmp_path / "q")
    assert err == ""
    assert (tmp_path / "q" / "fit.svg").is_file()


def test_default_output_folder_is_timestamped_under_runs(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = small_config(tmp_path)
    code, out, err = run(capsys, cfg, "-q", "--no-plots")
    assert code == 0, err
    folder = Path(out.strip())
    assert folder.parent == Path("runs")
    assert folder.name.endswith("-small")
    assert (tmp_path / folder / "result.json").is_file()
    assert not (tmp_path / folder / "fit.svg").exists()
    code, out2, _ = run(capsys, cfg, "-q", "--no-plots")
    assert code == 0 and out2.strip() != out.strip()  # a second run never overwrites the first


def test_list_plugins(capsys):
    code, out, err = run(capsys, "--list-plugins")
    assert code == 0
    assert "kelvin_voigt" in out and "scipy_lm" in out and "prbs" in out and "simulated" in out


def test_missing_config_argument(capsys):
    code, out, err = run(capsys)
    assert code == 2
    assert "mbus-run: error: a CONFIG file is required" in err
    assert "Traceback" not in err


# ---------------------------------------------------------------------------------------
# The installed console script
# ---------------------------------------------------------------------------------------
def console(*args, cwd: Path) -> subprocess.CompletedProcess:
    exe = shutil.which("mbus-run")
    if exe is None:
        pytest.skip("mbus-run console script not on PATH")
    env = {**os.environ, "CI": "1"}
    return subprocess.run([exe, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=300, env=env)


def test_console_script_runs_a_config(tmp_path):
    proc = console(small_config(tmp_path), "-o", tmp_path / "out", "--no-plots", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "k_sigma" in proc.stdout and "E_sigma" in proc.stdout
    assert proc.stderr == ""  # no progress bar in CI logs
    assert result(tmp_path / "out")["solver"]["success"]


def test_console_script_user_error(tmp_path):
    proc = console(tmp_path / "nope.yaml", cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [f"mbus-run: error: {tmp_path / 'nope.yaml'}: config file not found"]
    assert proc.stdout == ""


def test_console_script_bad_data_is_one_line(tmp_path):
    """A header-only CSV: numpy's 'Empty input file' warning must not reach stderr."""
    data = tmp_path / "rec.csv"
    data.write_text("t,u,y\n")
    proc = console(small_config(tmp_path, name="file", options={"path": str(data)}), "-o", tmp_path / "o", cwd=tmp_path)
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
