"""The ``mbus-analyze`` command (:func:`mbus_framework.analysis.cli.entry`: start-up fast paths,
no interpreter teardown) writes what :func:`~mbus_framework.analysis.cli.main` writes in a
plain Python process, and exits with the same statuses."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fakes.campaign_tables import TABLE_4_2, grouped_table
from mbus_framework.analysis.cli import main

ROOT = Path(__file__).resolve().parents[1]
ENTRY = "import sys; from mbus_framework.analysis.cli import entry; sys.argv[0] = 'mbus-analyze'; entry()"


def command(*argv, prelude: str = "") -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", prelude + ENTRY, *map(str, argv)], capture_output=True, text=True,
                          cwd=ROOT, timeout=600)


def same_files(a: Path, b: Path, names: list[str]) -> None:
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_classify_writes_the_same_files_as_in_process(tmp_path, capsys):
    grouped_table(TABLE_4_2, 4, seed=2).to_csv(tmp_path / "t.csv", index=False)
    done = command("classify", tmp_path / "t.csv", "--by", "material", "-o", tmp_path / "cmd")
    assert (done.returncode, done.stderr) == (0, "")
    assert main(["classify", str(tmp_path / "t.csv"), "--by", "material", "-o", str(tmp_path / "lib")]) == 0
    printed = capsys.readouterr().out
    assert done.stdout.replace("cmd", "lib") == printed
    same_files(tmp_path / "cmd", tmp_path / "lib", ["classification.csv", "classification.json", "confusion_matrices.csv"])
    assert (tmp_path / "cmd" / "discriminant_space.png").stat().st_size > 0


def test_crispness_with_statsmodels_and_sklearn_writes_the_same_tables(tmp_path, capsys):
    from virtual_apples import physics_table

    table, panel = physics_table(n=12, seed=4)
    table.to_csv(tmp_path / "properties.csv", index=False)
    panel.to_csv(tmp_path / "panel.csv", index=False)
    argv = ["crispness", tmp_path / "properties.csv", "--scores", tmp_path / "panel.csv", "--group", "cultivar",
            "--inputs", "k_sigma,k_tau", "--structures", "2", "--members", "2", "--restarts", "1", "--seed", "3",
            "--no-plots"]
    done = command(*argv, "-o", tmp_path / "cmd")
    assert (done.returncode, done.stderr) == (0, "")
    assert main([str(a) for a in argv] + ["-o", str(tmp_path / "lib")]) == 0
    capsys.readouterr()
    tables = sorted(p.name for p in (tmp_path / "lib").glob("*.csv"))
    assert "agreement.csv" in tables and "anova_group.csv" in tables
    same_files(tmp_path / "cmd", tmp_path / "lib", tables)


def test_the_command_applies_the_fast_paths_and_keeps_exit_statuses():
    probe = ("import atexit, sys\n"
             "def report():\n"
             "    from scipy._lib import _array_api\n"
             "    from mbus_framework.startup import _NoteInserter\n"
             "    print('notes', _array_api.FunctionDoc is _NoteInserter, 'f2py', type(sys.modules['numpy.f2py']).__name__)\n"
             "atexit.register(report)\n")
    done = command("classify", "no_such_table.csv", "--by", "material", prelude=probe)
    assert done.returncode == 2 and done.stderr.startswith("mbus-analyze: error: ")
    assert "notes True f2py _LazyModule" in done.stdout  # numpy.f2py not run (scipy's ``from numpy import *``)
    assert command("--help").returncode == 0 and "COMMAND" in command("--help").stdout
    assert command("--version").stdout.startswith("mbus-analyze ")
    missing = command()
    assert missing.returncode == 2 and "a COMMAND is required" in missing.stderr
    assert command("classify").returncode == 2  # argparse: the table and --by are required


@pytest.mark.parametrize("code", [0, 2, 3])
def test_entry_ends_with_mains_status(code, monkeypatch):
    """entry() hands main's status (or argparse's) to cli.finish."""
    import mbus_framework.analysis.cli as analysis_cli
    import mbus_framework.cli as cli

    ended = []
    monkeypatch.setattr(cli, "finish", ended.append)
    monkeypatch.setattr(analysis_cli, "main", lambda fast_start: code)
    analysis_cli.entry()

    def usage_error(fast_start):
        raise SystemExit(code)

    monkeypatch.setattr(analysis_cli, "main", usage_error)
    analysis_cli.entry()
    assert ended == [code, code]
