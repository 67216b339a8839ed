"""Issue 15, runs: no lost or mixed run folder (also with real concurrent processes), Ctrl-C
and SIGTERM at any moment stop the run and mark it interrupted, a killed lab acquisition is
recovered by the next run, and the README's re-fit command works for every backend's folder."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from mbus_framework.pipeline import interrupts
from mbus_framework.pipeline.run_folder import RunFolder, recover
from reliability_support import (
    MBUS_RUN,
    REPO,
    assert_clean_outcome,
    config,
    file_backend,
    python_env,
    run_cli,
    strict_json,
    write_gds_pair,
    write_lab_run,
    write_tuy_csv,
    write_tuy_npz,
    write_yaml,
)

POSIX = pytest.mark.skipif(os.name != "posix", reason="POSIX signals, flock and pseudo-terminals")
# A run that takes a few seconds, so a signal can land inside the fit.
#: A run whose search goes on for seconds whatever the speed of the fit: no minimum is ever
#: accepted (any input-related residual structure "significant" at p < 0.999), so every start and
#: the fallback search run (about 8 s of solver on 2 cores). A signal sent "0.3 s after the
#: measurement" must find the run still fitting, not in interpreter shutdown.
SLOW = config(excitation={"name": "prbs", "options": {"order": 9, "bit_width": 2.5e-6, "amplitude": 1.0,
                                                        "sample_rate": 6.25e6, "n_samples": 3000}},
              model={"name": "kelvin_voigt", "options": {"n_elements": 8}},
              solver={"name": "scipy_lm", "options": {"strategy": {"n_starts": 6, "accept_white": False,
                                                                   "significance": 0.999, "min_excess": 0.0}}})


def tmp_files(root: Path) -> list[Path]:
    return [p for p in root.rglob(".*.tmp")]


# -- one folder, one run ---------------------------------------------------------------------
def test_an_output_folder_holding_a_run_needs_overwrite(tmp_path):
    path = write_yaml(tmp_path / "run.yaml", config())
    out = tmp_path / "out"
    assert run_cli([path, "-o", out, "-q", "--set", "title=first"]).code == 0
    o = run_cli([path, "-o", out, "-q", "--set", "title=second"])
    assert o.code == 2
    assert_clean_outcome(o, [str(out)])
    assert "already holds a run (done" in o.err and "--overwrite" in o.err
    assert strict_json(out / "result.json")["title"] == "first"
    o = run_cli([path, "-o", out, "-q", "--set", "title=second", "--overwrite"])
    assert o.code == 0, o.err
    assert strict_json(out / "result.json")["title"] == "second"
    assert strict_json(out / "status.json")["status"] == "done"
    assert yaml.safe_load((out / "config.yaml").read_text())["title"] == "second"


def test_a_folder_whose_run_failed_before_measuring_is_reused(tmp_path):
    """Issue 27 item 7: a bad data file leaves only config.yaml and status 'failed'; the next try
    with the same -o needs no --overwrite. A failed folder that holds data is still protected."""
    bad = tmp_path / "empty.csv"
    bad.write_text("t,u,y\n")
    path = write_yaml(tmp_path / "run.yaml", config(backend=file_backend(bad)))
    out = tmp_path / "out"
    first = run_cli([path, "-o", out, "-q"])
    assert first.code != 0 and strict_json(out / "status.json")["status"] == "failed"
    again = run_cli([path, "-o", out, "-q"])
    assert "already holds" not in again.err and strict_json(out / "status.json")["status"] == "failed"
    good = write_yaml(tmp_path / "good.yaml", config())
    assert run_cli([good, "-o", out, "-q"]).code == 0
    assert strict_json(out / "status.json")["status"] == "done"
    (out / "status.json").write_text(json.dumps({"status": "failed"}))  # failed after writing results
    o = run_cli([good, "-o", out, "-q"])
    assert o.code == 2 and "already holds" in o.err


def test_a_folder_that_is_not_a_run_is_never_overwritten(tmp_path):
    path = write_yaml(tmp_path / "run.yaml", config())
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "chapter1.tex").write_text("precious")
    for extra in ([], ["--overwrite"]):
        o = run_cli([path, "-o", mine, *extra])
        assert o.code == 2
        assert_clean_outcome(o, [str(mine)])
    assert [p.name for p in mine.iterdir()] == ["chapter1.tex"]


def test_output_path_that_is_a_file_or_under_a_file(tmp_path):
    path = write_yaml(tmp_path / "run.yaml", config())
    existing = tmp_path / "notes.txt"
    existing.write_text("keep")
    for out in (existing, existing / "run"):
        o = run_cli([path, "-o", out])
        assert o.code == 2
        assert_clean_outcome(o, [str(existing)])
    assert existing.read_text() == "keep"


def test_an_empty_existing_folder_is_used(tmp_path):
    out = tmp_path / "empty"
    out.mkdir()
    assert run_cli([write_yaml(tmp_path / "run.yaml", config()), "-o", out, "-q"]).code == 0
    assert strict_json(out / "status.json")["status"] == "done"


@POSIX
def test_a_folder_in_use_is_refused_even_with_overwrite(tmp_path):
    out = tmp_path / "busy"
    with RunFolder.create(out):
        o = run_cli([write_yaml(tmp_path / "run.yaml", config()), "-o", out, "--overwrite"])
    assert o.code == 2
    assert f"{out}: in use by another run (pid {os.getpid()}" in o.err


# -- real concurrent processes ---------------------------------------------------------------
STARTER = textwrap.dedent("""
    import os, sys, time
    from mbus_framework.cli import main          # import everything first ...
    import mbus_framework.pipeline.run, mbus_plugins.backends.simulated, mbus_plugins.solvers.scipy_lm
    from mbus_framework.interfaces.registry import default_registry
    default_registry()
    ready, go = sys.argv[1], sys.argv[2]
    open(ready, "w").close()
    while not os.path.exists(go):                # ... then start together
        time.sleep(0.001)
    sys.exit(main(sys.argv[3:]))
""")


def start_together(tmp_path: Path, argvs: list[list[str]]) -> list[subprocess.CompletedProcess]:
    """Run ``mbus-run`` in len(argvs) processes that all enter main() within a millisecond,
    at 0.1 s past a whole second (so default folder names share their time stamp)."""
    go = tmp_path / "go"
    procs, readies = [], []
    for k, argv in enumerate(argvs):
        ready = tmp_path / f"ready{k}"
        readies.append(ready)
        procs.append(subprocess.Popen([sys.executable, "-c", STARTER, str(ready), str(go), *map(str, argv)],
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=python_env(),
                                      cwd=tmp_path))
    deadline = time.time() + 120
    while not all(r.exists() for r in readies):
        assert time.time() < deadline, "processes did not start"
        time.sleep(0.01)
    now = time.time()
    time.sleep((1.1 - now % 1.0) % 1.0)
    go.touch()
    results = []
    for p in procs:
        out, err = p.communicate(timeout=300)
        results.append(subprocess.CompletedProcess(p.args, p.returncode, out, err))
    return results


def consistent(folder: Path) -> str:
    """The title every file of a finished run folder agrees on (config, result, status)."""
    title = yaml.safe_load((folder / "config.yaml").read_text())["title"]
    assert strict_json(folder / "result.json")["title"] == title
    assert strict_json(folder / "status.json")["status"] == "done"
    return title


@POSIX
def test_two_processes_with_the_same_output_folder(tmp_path):
    path = write_yaml(tmp_path / "run.yaml", config())
    out = tmp_path / "same"
    results = start_together(tmp_path, [[path, "-o", out, "-q", "--set", f"title={t}"] for t in ("A", "B")])
    codes = sorted(r.returncode for r in results)
    assert codes == [0, 2], [(r.returncode, r.stderr) for r in results]
    winner = next(r for r in results if r.returncode == 0)
    loser = next(r for r in results if r.returncode == 2)
    assert ("in use by another run" in loser.stderr) or ("already holds a run" in loser.stderr), loser.stderr
    assert consistent(out) == winner.args[-1].split("=")[1]
    assert tmp_files(tmp_path) == []


@POSIX
def test_two_processes_started_in_the_same_second_get_two_folders(tmp_path):
    path = write_yaml(tmp_path / "run.yaml", config(output={"directory": str(tmp_path / "runs"), "plots": False}))
    for attempt in range(3):
        results = start_together(tmp_path, [[path, "-q", "--set", f"title={t}{attempt}"] for t in ("A", "B")])
        assert [r.returncode for r in results] == [0, 0], [r.stderr for r in results]
        folders = [Path(r.stdout.strip()) for r in results]
        folders = [f if f.is_absolute() else tmp_path / f for f in folders]
        assert folders[0] != folders[1]
        assert sorted(consistent(f) for f in folders) == [f"A{attempt}", f"B{attempt}"]
        stamps = {f.name.split("-run")[0] for f in folders}
        if len(stamps) == 1:  # the same second: one of them is <stamp>-run-2
            assert sorted(f.name[-2:] for f in folders) == ["-2", "un"]
            return
    pytest.skip("the two processes never started in the same second on this machine")


# -- Ctrl-C and SIGTERM ----------------------------------------------------------------------
def spawn(argv: list) -> subprocess.Popen:
    return subprocess.Popen([*MBUS_RUN, *map(str, argv)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=python_env())


def wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120) -> bool:
    deadline = time.time() + timeout
    while not path.exists():
        if proc.poll() is not None or time.time() > deadline:
            return False
        time.sleep(0.002)
    return True


@POSIX
@pytest.mark.parametrize("moment, after", [
    ("run folder created", 0.0),
    ("measurement saved", 0.05),   # about 50 ms into the fit
    ("measurement saved", 0.3),
    pytest.param("measurement saved", 1.0, marks=pytest.mark.slow),
])
def test_ctrl_c_at_any_moment_exits_130_and_marks_the_run(tmp_path, moment, after):
    out = tmp_path / "out"
    proc = spawn([write_yaml(tmp_path / "run.yaml", SLOW), "-o", out, "--no-plots"])
    marker = out / ("status.json" if moment == "run folder created" else "measurement.json")
    if not wait_for(marker, proc):
        proc.kill()
        pytest.fail(f"{marker.name} never appeared: {proc.communicate()}")
    time.sleep(after)
    if proc.poll() is not None:  # finished before the moment came (not a swallowed signal: none was sent)
        pytest.skip(f"the run ended within {after} s after its {moment.split()[0]}, before the signal")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "mbus-run: interrupted"
    assert "Traceback" not in err
    status = strict_json(out / "status.json")
    assert status["status"] == "interrupted" and status["error"] == "interrupted (Ctrl-C)"
    assert tmp_files(tmp_path) == []
    assert not (out / "result.json").exists()


@POSIX
def test_ctrl_c_while_the_figures_are_written_keeps_the_result(tmp_path):
    """After the fit: result.json stays (what was estimated is not lost), the run is marked
    interrupted, no half-written figure or report is left."""
    out = tmp_path / "out"
    proc = spawn([REPO / "configs" / "potato.yaml", "-o", out])
    if not wait_for(out / "result.json", proc):
        proc.kill()
        pytest.fail(f"result.json never appeared: {proc.communicate()}")
    time.sleep(0.05)  # drawing the figures takes about a second
    if proc.poll() is not None:
        pytest.skip("the figures were written before the moment came")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "mbus-run: interrupted" and "Traceback" not in err
    assert strict_json(out / "status.json")["status"] == "interrupted"
    assert strict_json(out / "result.json")["properties"]["E_sigma"] > 0
    assert tmp_files(tmp_path) == []


@POSIX
def test_sigterm_exits_143_and_marks_the_run(tmp_path):
    out = tmp_path / "out"
    proc = spawn([write_yaml(tmp_path / "run.yaml", SLOW), "-o", out, "--no-plots"])
    assert wait_for(out / "measurement.json", proc)
    time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "mbus-run: terminated (SIGTERM)"
    assert strict_json(out / "status.json")["status"] == "interrupted"
    assert tmp_files(tmp_path) == []


@POSIX
def test_a_swallowed_ctrl_c_still_stops_the_run(tmp_path, monkeypatch):
    """Compiled code can swallow a KeyboardInterrupt (scipy's Sobol initialisation reports
    "Exception ignored in ..." and carries on, about 50 ms into a fit); the next checkpoint
    raises it again, so the run never finishes as if nothing happened, and nothing is printed
    but the one line."""
    from mbus_plugins.solvers.scipy_lm import ScipyLM

    real = ScipyLM.solve
    calls = []

    class Swallower:  # an exception in __del__ goes the same way: "Exception ignored", then on
        def __del__(self):
            calls.append("swallowed")
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)

    def swallowing(self, problem, progress=None):
        Swallower()
        return real(self, problem, progress)

    monkeypatch.setattr(ScipyLM, "solve", swallowing)
    out = tmp_path / "out"
    o = run_cli([write_yaml(tmp_path / "run.yaml", config()), "-o", out], timeout=60)
    assert calls == ["swallowed"]
    assert o.code == 130 and o.err.strip() == "mbus-run: interrupted"
    assert strict_json(out / "status.json")["status"] == "interrupted"
    assert not (out / "result.json").exists()


def test_signals_are_held_back_while_a_file_is_written(tmp_path):
    from mbus_framework.pipeline.storage import atomic_write_text

    with interrupts.handling():
        with pytest.raises(KeyboardInterrupt):
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                atomic_write_text(tmp_path / "whole.txt", "all of it")  # not interrupted
                assert (tmp_path / "whole.txt").read_text() == "all of it"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["whole.txt"]


# -- a lab acquisition killed or terminated ----------------------------------------------------
lab = pytest.importorskip("test_lab_backend", reason="lab backend tests need pyvisa-py and ptys")


@pytest.fixture
def rig():
    if not hasattr(os, "openpty"):
        pytest.skip("needs pseudo-terminals")
    from fakes.bench import Bench
    from fakes.ds340 import FakeDS340
    from fakes.gds2000 import FakeGDS2000

    with FakeDS340() as gen, FakeGDS2000(record_points=lab.RECORD_POINTS) as scope:
        Bench(gen, scope, lab.model(), list(lab.TRUTH.values()), noise=0.01, seed=3)
        yield gen, scope


def lab_config(tmp_path: Path, gen, scope, shots: int, settle: float = 0.0) -> Path:
    options = lab.lab_options(gen, scope, shots=shots)
    options["scope"]["settle"] = settle
    return write_yaml(tmp_path / "rig.yaml", {
        "title": "lab rig against fake instruments", "sample": lab.SAMPLE,
        "model": {"name": "kelvin_voigt", "options": {"n_elements": 10},
                  "initial": {k: 1.3 * v for k, v in lab.TRUTH.items()}},
        "excitation": {"name": "prbs", "options": lab.PRBS},
        "backend": {"name": "lab", "options": options}, "output": {"plots": False}})


def acquisition(out: Path) -> dict:
    return json.loads((out / "shots" / "acquisition.json").read_text())


def wait_for_shots(out: Path, proc, count: int) -> None:
    deadline = time.time() + 120
    while True:
        assert proc.poll() is None, proc.communicate()
        assert time.time() < deadline
        try:
            if acquisition(out)["shots_saved"] >= count:
                return
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.01)


@POSIX
def test_sigterm_during_a_lab_acquisition(tmp_path, rig):
    gen, scope = rig
    out = tmp_path / "runs" / "lab"
    proc = spawn([lab_config(tmp_path, gen, scope, shots=60, settle=0.05), "-o", out, "--no-plots"])
    wait_for_shots(out, proc, 2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    acq = acquisition(out)
    assert acq["status"] == "interrupted" and acq["error"] == "terminated (SIGTERM)"
    assert acq["shots_saved"] == len(list((out / "shots").glob("shot_*.npz")))
    assert strict_json(out / "status.json")["status"] == "interrupted"
    assert tmp_files(tmp_path) == []


@POSIX
def test_sigkill_during_a_lab_acquisition_is_recovered_by_the_next_run(tmp_path, rig):
    gen, scope = rig
    runs = tmp_path / "runs"
    out = runs / "killed"
    proc = spawn([lab_config(tmp_path, gen, scope, shots=60, settle=0.05), "-o", out, "--no-plots"])
    wait_for_shots(out, proc, 2)
    proc.kill()
    proc.communicate(timeout=60)
    assert acquisition(out)["status"] == "acquiring"
    stray = out / "shots" / ".shot_0099.npz.k1ll3d.tmp"  # as a kill in the middle of a write leaves it
    stray.write_bytes(b"half a shot")
    assert strict_json(out / "status.json")["status"] == "running"

    # The next run in the same parent folder recovers it.
    assert run_cli([write_yaml(tmp_path / "next.yaml", config()), "-o", runs / "next", "-q"]).code == 0
    status = strict_json(out / "status.json")
    acq = acquisition(out)
    assert status["status"] == "interrupted" and "abandoned" in status["error"]
    assert acq["status"] == "interrupted" and "abandoned" in acq["error"] and "while acquiring" in acq["error"]
    assert tmp_files(tmp_path) == []

    # And it re-fits, saying the acquisition was cut short.
    saved = acq["shots_saved"]
    refit = run_cli(["--set", f"backend={{name: file, options: {{path: {out}}}}}", out / "config.yaml",
                     "-o", tmp_path / "refit"])
    assert refit.code == 0, refit.err
    warning = strict_json(tmp_path / "refit" / "result.json")["warnings"][0]
    assert warning.startswith(f"measurement: acquisition interrupted: {saved} of 60 shots saved (abandoned")


def test_recover_leaves_a_live_run_alone(tmp_path):
    with RunFolder.create(tmp_path / "live") as folder:
        assert recover(folder.path) is False
        assert strict_json(folder.path / "status.json")["status"] == "running"


# -- the README's re-fit command, for every backend's run folder --------------------------------
def refit_matches(tmp_path: Path, cfg: dict, name: str) -> None:
    run = tmp_path / f"{name}-run"
    first = run_cli([write_yaml(tmp_path / f"{name}.yaml", cfg), "-o", run, "-q"])
    assert first.code == 0, first.err
    # mbus-run runs/<run>/config.yaml --set 'backend={name: file, options: {path: runs/<run>}}'
    again = run_cli([run / "config.yaml", "--set", f"backend={{name: file, options: {{path: {run}}}}}",
                     "-o", tmp_path / f"{name}-refit", "-q"])
    assert again.code == 0, again.err
    original = strict_json(run / "result.json")["parameters"]
    refit = strict_json(tmp_path / f"{name}-refit" / "result.json")["parameters"]
    assert refit == pytest.approx(original, rel=1e-9)


def test_refit_of_a_simulated_run(tmp_path):
    refit_matches(tmp_path, config(), "simulated")


@pytest.mark.parametrize("kind", ["csv", "npz", "gds_raw", "gds_detail", "lab_folder"])
def test_refit_of_a_file_backend_run(tmp_path, kind):
    data = tmp_path / "data"
    data.mkdir()
    if kind == "csv":
        backend = file_backend(write_tuy_csv(data))
    elif kind == "npz":
        backend = file_backend(write_tuy_npz(data))
    elif kind.startswith("gds"):
        ch1, ch2 = write_gds_pair(data, kind.split("_")[1])
        backend = file_backend(ch1, response_path=str(ch2))
    else:
        backend = file_backend(write_lab_run(data / "lab"))
    refit_matches(tmp_path, config(backend=backend), kind)


@POSIX
def test_refit_of_a_lab_run(tmp_path, rig):
    gen, scope = rig
    run = tmp_path / "lab-run"
    assert run_cli([lab_config(tmp_path, gen, scope, shots=2), "-o", run, "-q"], timeout=120).code == 0
    again = run_cli([run / "config.yaml", "--set", f"backend={{name: file, options: {{path: {run}}}}}",
                     "-o", tmp_path / "refit", "-q"], timeout=120)
    assert again.code == 0, again.err
    assert strict_json(tmp_path / "refit" / "result.json")["parameters"] == pytest.approx(
        strict_json(run / "result.json")["parameters"], rel=1e-9)


def test_refit_of_a_run_still_in_progress_is_refused(tmp_path):
    run = tmp_path / "busy"
    with RunFolder.create(run):
        np.savetxt(run / "measurement.csv", np.zeros((20, 3)), delimiter=",", header="t,u,y", comments="")
        o = run_cli([write_yaml(tmp_path / "r.yaml", config(backend=file_backend(run))), "-o", tmp_path / "o"])
    assert o.code == 2
    assert "still in progress" in o.err
