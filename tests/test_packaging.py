"""The house's layout: what installs, under which names, and how big a module may grow."""
from __future__ import annotations

import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

REPO = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
#: folder -> installed package name (pyproject's package-dir)
INSTALLED_AS = {"mbus": "mbus", "mbus_framework": "mbus_framework", "plugins": "mbus_plugins"}


def package_folders() -> set[str]:
    found = set()
    for folder, name in INSTALLED_AS.items():
        for init in (REPO / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(REPO / folder).parts
            found.add(".".join((name, *rel)))
    return found


def test_every_package_folder_is_installed():
    """pyproject lists its packages explicitly (the plugins folder is mapped to mbus_plugins);
    a folder missing from the list would be left out of a wheel."""
    listed = set(PYPROJECT["tool"]["setuptools"]["packages"])
    assert listed == package_folders()
    assert PYPROJECT["tool"]["setuptools"]["package-dir"]["mbus_plugins"] == "plugins"


def test_entry_points_name_installed_modules():
    for name, target in PYPROJECT["project"]["entry-points"]["mbus_framework"].items():
        assert target.startswith("mbus_plugins."), (name, target)
        assert target.rsplit(".", 1)[0] in package_folders() or target in package_folders(), target


def test_both_commands_print_the_version():
    from mbus_framework import __version__

    for command in ("mbus_framework.cli", "mbus_framework.analysis.cli"):
        out = subprocess.run([sys.executable, "-c", f"import sys; from {command} import main; sys.exit(main(['--version']))"],
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0 and out.stdout.strip().endswith(__version__), (command, out)


def test_analysis_files_are_grouped_in_subpackages():
    """No file in an analysis folder shares its name prefix (before the first '_') with two
    or more siblings: an analysis with several files gets a subpackage of its own."""
    for folder in [REPO / "mbus_framework/analysis", *(p for p in (REPO / "mbus_framework/analysis").iterdir() if p.is_dir())]:
        prefixes = Counter(p.stem.split("_")[0] for p in folder.glob("*.py") if p.stem != "__init__")
        crowded = {k: n for k, n in prefixes.items() if n >= 3}
        assert not crowded, (folder.relative_to(REPO).as_posix(), crowded)


def test_no_plugin_module_is_over_500_lines():
    long = [f"{p.relative_to(REPO).as_posix()}: {n}" for p in sorted((REPO / "plugins").rglob("*.py"))
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 500]
    assert not long, long
