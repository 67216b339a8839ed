"""``mbus-run`` ends its process without Python's teardown (issue 24: 0.1-0.3 s after a run is
done): atexit handlers still run, stdout and stderr arrive whole, exit codes are main's, and a
process with another live thread (Dask, a plugin's) exits the usual way."""
from __future__ import annotations

import subprocess
import sys
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def python(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code, *args], cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_the_console_script_is_entry():
    (script,) = [ep for ep in metadata.entry_points(group="console_scripts") if ep.name == "mbus-run"]
    assert script.value == "mbus_framework.cli:entry", "reinstall: pip install -e ."


def test_a_run_ends_with_its_output_flushed_and_atexit_handlers_run(tmp_path):
    marker = tmp_path / "atexit-ran"
    code = ("import atexit, pathlib; atexit.register(pathlib.Path(%r).write_text, 'yes')\n"
            "from mbus_framework.cli import entry; entry()") % str(marker)
    done = python(code, "configs/potato.yaml", "-o", str(tmp_path / "run"), "--no-plots")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("mbus identification:") and f"output: {tmp_path / 'run'}" in done.stdout
    assert marker.read_text() == "yes"
    assert (tmp_path / "run" / "report.html").is_file()


def test_an_error_keeps_its_exit_code_and_message(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: {name: kelvin_voigt}\n")
    done = python("from mbus_framework.cli import entry; entry()", str(bad), "-o", str(tmp_path / "run"))
    assert done.returncode == 2
    assert done.stderr.startswith("mbus-run: error: ") and done.stderr.count("\n") == 1


def test_finish_flushes_buffered_output_and_waits_for_other_threads(tmp_path):
    marker = tmp_path / "thread-done"
    alone = python("import sys; from mbus_framework.cli import finish\n"
                   "print('to stdout', end=''); sys.stderr.write('to stderr'); finish(4)")
    assert (alone.returncode, alone.stdout, alone.stderr) == (4, "to stdout", "to stderr")
    threaded = python("import pathlib, threading, time; from mbus_framework.cli import finish\n"
                      "threading.Thread(target=lambda: (time.sleep(0.3), pathlib.Path(%r).write_text('done'))).start()\n"
                      "print('x', end=''); finish(3)" % str(marker))
    assert (threaded.returncode, threaded.stdout) == (3, "x")
    assert marker.read_text() == "done"  # the usual exit joined the thread
